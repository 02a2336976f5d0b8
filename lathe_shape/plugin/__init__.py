"""The Mitsuba plugins: the ``lathe`` shape, the scene geometry that merges
exact lathe hits with Mitsuba's, the ``lathe_path`` integrator and their
registration for JIT variants."""
