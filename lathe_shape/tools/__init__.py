"""Tools built on the plugins: scene loading and XML edits, images and
metrics, frames and turntables, denoising, POV-Ray export and scenes,
gradients and inverse design. A user library: it imports the plugins,
surfaces, kernels and profiles, never ``lathe_shape.cli`` or
``lathe_shape.validation`` (the harnesses that scripts and tests use)."""
