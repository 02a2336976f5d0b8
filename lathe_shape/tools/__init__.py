"""Tools built on the plugins: scene loading and XML edits, images and
metrics, turntables, the white furnace, benchmarks and validation references."""
