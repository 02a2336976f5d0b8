"""Validation harnesses: the leak and watertightness tests, benchmarks, the
white furnace, the paper's figures, the POV-Ray comparison and the
reference curves and rays they share. Scripts and tests use them; they sit
above the command line (they may drive ``lathe_shape.cli``), and nothing
in the package below them imports them."""
