"""The documentation's generated and listed parts are current: the command-line reference is what the parsers give,
the Python API reference documents every public name, and the site's navigation (mkdocs.yml) lists every page."""

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import ocalib

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("cli_reference", ROOT / "docs" / "cli_reference.py")
cli_reference = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cli_reference)


def test_the_cli_reference_is_what_the_parsers_give():
    assert (ROOT / "docs" / "reference" / "cli.md").read_text() == cli_reference.cli_markdown(), (
        "refresh it: python docs/cli_reference.py"
    )


def test_the_cli_reference_lists_every_command_and_option_of_the_help():
    from ocalib.cli import COMMANDS

    page = cli_reference.cli_markdown()
    for name in COMMANDS:
        assert f"## `ocalib {name}`" in page
        if name == "train":
            continue
        help_text = subprocess.run(
            [sys.executable, "-m", "ocalib", name, "--help"],
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, "COLUMNS": "1000"},  # no option broken over two lines
        ).stdout
        section = page.split(f"## `ocalib {name}`", 1)[1].split("\n## ", 1)[0]
        # the options the help defines: the start of its argument lines ("  --align, --no-align  text")
        defined = {
            o for line in re.findall(r"^  (-.*?)(?:  |$)", help_text, re.M) for o in re.findall(r"--[\w-]+", line)
        }
        assert defined, help_text
        for option in defined - {"--help"}:
            assert f"`{option}`" in section, f"ocalib {name}: {option} is not in the reference"


def test_a_changed_option_makes_the_check_fail(monkeypatch):
    page = cli_reference.cli_markdown()
    monkeypatch.setattr(cli_reference, "cli_markdown", lambda: page.replace("`--out`", "`--output`", 1))
    monkeypatch.setattr(sys, "argv", ["cli_reference.py", "--check"])
    assert cli_reference.main() == 1


@pytest.mark.parametrize("name", ocalib.__all__)
def test_the_python_reference_documents_each_public_name(name):
    page = (ROOT / "docs" / "reference" / "python.md").read_text()
    assert f"::: {ocalib._PUBLIC[name]}.{name}\n" in page


def test_the_site_lists_every_page():
    config = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=yaml.BaseLoader)

    def pages(nav):
        for item in nav:
            for value in item.values() if isinstance(item, dict) else [item]:
                yield from pages(value) if isinstance(value, list) else [value]

    listed = set(pages(config["nav"]))
    on_disk = {str(p.relative_to(ROOT / "docs")) for p in (ROOT / "docs").rglob("*.md")} - {"README.md"}
    assert on_disk | {"index.md", "contents.md"} == listed
