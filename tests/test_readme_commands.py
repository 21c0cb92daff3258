"""Every command the README shows parses, so a renamed command, subcommand or option fails here
rather than for a user. `--help` alone would not do: it exits before tyro rejects an unknown
option. So each command runs as written, in an empty folder where its placeholder paths do not
exist: it must fail on the missing input, never on its command line (tyro's exit status 2)."""

import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PLUGIN_COMMANDS = ("ns-train", "ns-eval", "ns-viewer", "ns-render", "ns-export", "wild-thermal-")


def readme_commands():
    """The README's indented command lines that run a plugin or nerfstudio command (comments dropped)."""
    commands = []
    for line in (ROOT / "README.md").read_text().splitlines():
        if not line.startswith("    "):
            continue
        words = shlex.split(line.split("  #")[0].strip())
        words = [w.replace(".venv/bin/", "") for w in words]
        if words and words[0] == "torchrun":  # the launcher's module, as one process runs it (it parses first)
            commands.append(["python", *words[words.index("-m") :]])
            continue
        for i, word in enumerate(words):  # `setup && .venv/bin/wild-thermal-demo`: the command after &&
            if word.startswith(PLUGIN_COMMANDS):
                commands.append(words[i:])
                break
    return commands


def test_the_readme_shows_the_commands_a_user_needs():
    names = {c[0] for c in readme_commands()}
    assert {
        "ns-train",
        "ns-eval",
        "ns-viewer",
        "wild-thermal-demo",
        "wild-thermal-render",
        "wild-thermal-export",
    } <= names


@pytest.mark.slow
@pytest.mark.parametrize("command", readme_commands(), ids=lambda c: " ".join(c[:3]))
def test_readme_command_parses(command, tmp_path):
    args = command[1:] or ["--help"]  # a command without arguments would run its whole job
    program = sys.executable if command[0] == "python" else str(BIN / command[0])
    result = subprocess.run([program, *args], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    output = result.stdout + result.stderr
    assert result.returncode != 2 and "Unrecognized" not in output, f"{' '.join(command)}\n{output[-2000:]}"
    if command[1:]:
        assert result.returncode != 0, output[-2000:]  # it did fail, on the missing input
