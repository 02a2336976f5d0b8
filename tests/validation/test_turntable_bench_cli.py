"""scripts/bench_turntable.py's options and errors (no denoiser needed)."""

from __future__ import annotations

import pytest
from conftest import SCENES, VARIANT

from lathe_shape.cli.common import CliError
from lathe_shape.validation.turntable_bench import frame_times, run_bench


@pytest.mark.parametrize(("option", "value", "message"), [
    ("--rounds", "0", "--rounds must be at least 1, got 0"),  # was: NaN timings and NumPy warnings
    ("--frames", "0", "--frames must be at least 1, got 0"),  # was: IndexError
    ("--spp", "0", "--spp must be at least 1, got 0"),
    ("--clean-spp", "-1", "--clean-spp must be at least 0, got -1"),
])
def test_bench_checks_its_counts(capsys, option, value, message):
    assert run_bench(["--variant", VARIANT, option, value]) == 2
    err = capsys.readouterr().err
    assert err == f"bench_turntable.py: error: {message}\n"


def test_frame_times_reports_the_turntable_error():
    # lathe-turntable's own message, not "IndexError: list index out of range"
    # (its stderr is captured while it runs).
    with pytest.raises(CliError, match="lathe-turntable: error: --threads must be at least 1, got 0"):
        frame_times(str(SCENES / "wine_glass.xml"), VARIANT, 1, 1, 8, ["mesh_segments=8"],
                    ["--threads", "0"], rounds=1)
