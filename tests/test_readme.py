"""The README's commands run as written: every ``sh`` block's command lines are read from the README itself; those
that need nothing but this repository (no real robot, tracker or earlier session) and take seconds are run in a
shell whose PATH starts with the virtual environment's bin folder (what ``. .venv/bin/activate`` does), from a
folder holding a copy of the sample data. Files the README names are checked to exist."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
#: a command that needs something this repository does not give: a session or result of an earlier run, a real
#: device, a placeholder
NEEDS_MORE = re.compile(r"\bSESSION\b|\bS\b|S\.session|\[|@\d|/dev/|ipp://|sessions/|\.result\.yaml|result\.yaml "
                        r"--targets|step\.yaml|^make ")
#: seconds, not minutes: a dry run plans and checks but moves nothing; the sample identifies in seconds
CHEAP = re.compile(r"--dry-run|^identify identify/data/")


def _commands() -> list[str]:
    out = []
    for block in re.findall(r"```sh\n(.*?)```", README, re.S):
        for line in block.splitlines():
            command = line.split("  #")[0].strip()
            if command.startswith(("acquire", "identify", ".venv/bin/", "make")):
                out.append(command)
    return out


COMMANDS = _commands()
RUN = [c for c in COMMANDS if not NEEDS_MORE.search(c) and CHEAP.search(c)]


def test_the_readme_has_commands_to_run():
    assert len(RUN) >= 4, RUN
    assert any(c.startswith("acquire") for c in RUN) and any(c.startswith("identify") for c in RUN)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A working folder with the sample data where the README expects it, and the README's site file with a cell."""
    here = tmp_path_factory.mktemp("readme")
    shutil.copytree(ROOT / "identify" / "data", here / "identify" / "data")
    cell = re.search(r"```yaml\n(schema: 1 .*?\ncell:.*?)```", README, re.S)
    assert cell, "the README's cell snippet is a whole site file (schema: 1 first)"
    (here / "cell.yaml").write_text(cell.group(1))
    return here


@pytest.mark.slow
@pytest.mark.parametrize("command", RUN)
def test_a_readme_command_runs_as_written(command, folder):
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    done = subprocess.run(command, shell=True, cwd=folder, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"{command}\n{done.stderr[-2000:]}"
    assert "Traceback" not in done.stderr


@pytest.mark.slow
def test_the_cell_snippet_is_a_site_file_that_plans(folder):
    """The README's cell.yaml, with the command the README gives for it."""
    line = re.search(r"`(acquire [^`]*--config cell\.yaml)`", README)
    assert line
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    done = subprocess.run(line.group(1), shell=True, cwd=folder, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]


def test_files_and_links_the_readme_names_exist():
    named = set(re.findall(r"\]\(([^)#]+)\)", README)) | set(re.findall(r"`((?:docs|config|identify|acquire|"
                                                                        r"scripts|bench)/[\w./-]+\.\w+)`", README))
    missing = sorted(p for p in named if not p.startswith("http") and not (ROOT / p).exists())
    assert missing == []
    assert "DESIGN.md" not in README and "shared/" not in README
