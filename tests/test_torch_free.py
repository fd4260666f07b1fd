"""The numpy and COLMAP paths import no torch: the on-line rig estimator's modules, and ``ocalib calibrate`` up to its
input checks, whose errors therefore take a fraction of a second."""

import subprocess
import sys

import pytest


@pytest.mark.parametrize(
    "module",
    ["ocalib.rigba", "ocalib.rigba.change", "ocalib.rigba.online", "ocalib.cli.calibrate", "ocalib.calibnet.sequence"],
)
def test_importing_imports_no_torch(module):
    code = f"import sys, {module}; print('torch' in sys.modules, 'ocalib.eval' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


def test_calibrate_says_an_input_error_before_importing_torch(tmp_path):
    code = (
        "import sys\nfrom ocalib.cli import main\n"
        f"rc = main(['calibrate', '--sequence', {str(tmp_path)!r}])\n"
        "print(rc, 'torch' in sys.modules)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.stdout.split() == ["2", "False"]
    assert run.stderr.strip() == f"ocalib calibrate: error: {tmp_path}: the folder is empty"
