"""The README's examples run as written, and its filter table matches the registry."""

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path


from pcprep.meshlab_bridge.docs import BEGIN, END, filter_table_markdown

README = Path(__file__).resolve().parent.parent / "README.md"


def _blocks(lang):
    return re.findall(rf"```{lang}\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def test_readme_opens_with_the_two_commands():
    head = README.read_text(encoding="utf-8").split("\n## ")[0]
    assert "pcprep report --quick" in head
    assert 'pip install ".[test]"' in head and "python -m pytest" in head


def test_filter_table_is_the_generated_one():
    text = README.read_text(encoding="utf-8")
    start, end = text.index(BEGIN), text.index(END) + len(END)
    assert text[start:end] == filter_table_markdown()


def test_each_python_example_runs_on_its_own(tmp_path, monkeypatch):
    blocks = _blocks("python")
    assert len(blocks) >= 2
    for i, code in enumerate(blocks):
        folder = tmp_path / f"example{i}"
        folder.mkdir()
        monkeypatch.chdir(folder)
        exec(compile(code, "README.md", "exec"), {"__name__": "__readme__"})  # noqa: S102


def test_the_command_line_example_runs_on_its_own(tmp_path):
    commands = [line[2:] for block in _blocks("console") for line in block.splitlines()
                if line.startswith("$ pcprep ") and "report" not in line and "bench" not in line]
    assert len(commands) >= 8
    for cmd in commands:
        argv = [sys.executable, "-m", "pcprep", *shlex.split(cmd)[1:]]
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=600,
                              env=dict(os.environ), cwd=tmp_path)
        assert proc.returncode == 0, f"{cmd}: {proc.stderr}"
