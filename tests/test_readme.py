"""The README's promises: two set-up commands first, and a Python example that runs."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_opens_with_the_two_setup_commands():
    text = README.read_text()
    first_block = re.search(r"```\n(.*?)```", text, re.S).group(1).split()
    assert first_block == ["make", "demo", "make", "test"]


def test_python_example_runs_and_finds_the_fault(capsys):
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    exec(compile(code, "README.md", "exec"), {})
    out = capsys.readouterr().out
    # The headline now says its number is the constrained fit (issue 12, one number per fault).
    assert out.startswith("VERDICT: Fault (fit with only R1 changed): coil 1 resistance R1")
