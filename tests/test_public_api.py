"""The public API: each name ``ocalib`` exports is the object of its module, ``import ocalib`` loads none of them
(no torch), and the README's Python examples run: one for each public name, in order, on small data."""

import re
import subprocess
import sys
from importlib import import_module
from pathlib import Path

import pytest

import ocalib

README = Path(__file__).parents[1] / "README.md"


@pytest.mark.parametrize("name", ocalib.__all__)
def test_each_public_name_is_its_modules_object(name):
    assert getattr(ocalib, name) is getattr(import_module(ocalib._PUBLIC[name]), name)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'calibrate'"):
        ocalib.calibrate  # noqa: B018


def test_importing_ocalib_loads_no_torch():
    code = "import sys, ocalib; print('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "False\n"


def readme_examples() -> list[str]:
    """The README's Python blocks, in order (they continue one another)."""
    return re.findall(r"```python\n(.*?)```", README.read_text(), re.S)


def test_the_readmes_python_examples_run_in_order():
    namespace = {}
    for block in readme_examples():
        exec(compile(block, "README.md", "exec"), namespace)


@pytest.mark.parametrize("name", ocalib.__all__)
def test_each_public_name_has_an_example_that_calls_it(name):
    """Each public name is imported from ocalib and used in a README example of its own."""
    calls = [b for b in readme_examples() if re.search(rf"from ocalib import .*\b{name}\b", b) and f"{name}(" in b]
    assert calls, f"no README example imports and calls {name}"
