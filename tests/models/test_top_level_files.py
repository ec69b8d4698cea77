"""The file named on the command line and a scene's model are read like referenced files:
regular files only (a FIFO cannot hang phc), bounded size, and a scene's model inside the
scene's directory or the one above it (the models/scenes/ layout) unless allowed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[2]
MSD = (REPO / "models" / "mass_spring_damper.yaml").read_text()


def phc(*args, env=None, timeout=SUBPROCESS_TIMEOUT):
    full_env = {k: v for k, v in os.environ.items() if k != "PHC_ALLOW_PATH"}
    full_env.update(env or {})
    return subprocess.run([sys.executable, "-m", "phc", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=full_env)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs named pipes")
def test_a_fifo_named_on_the_command_line_is_refused_at_once(tmp_path):
    fifo = tmp_path / "model.yaml"
    os.mkfifo(fifo)
    run = phc("validate", fifo)  # a blocking read would hang until the timeout fails the test
    assert run.returncode == 1
    assert run.stderr.startswith(f"{fifo}:1:1: cannot read") and "not a regular file" in run.stderr


def test_an_oversized_model_file_is_refused(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (2 * 2**20) + "\n" + MSD)
    run = phc("validate", big, env={"PHC_MAX_MODEL_FILE_MB": "1"})
    assert run.returncode == 1, run.stdout
    assert "above the limit" in run.stderr


@pytest.mark.parametrize("layout, ok", [
    ({"models/m.yaml": MSD, "models/scenes/s.yaml": "format_version: 1\nmodel: ../m.yaml\n"}, True),
    ({"m.yaml": MSD, "s.yaml": "format_version: 1\nmodel: m.yaml\n"}, True),
    ({"m.yaml": MSD, "a/b/s.yaml": "format_version: 1\nmodel: ../../m.yaml\n"}, False),
    ({"a/s.yaml": "format_version: 1\nmodel: /etc/passwd\n"}, False),
])
def test_a_scenes_model_stays_in_its_tree(tmp_path, layout, ok):
    for name, text in layout.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    scene = next(tmp_path / n for n in layout if n.endswith("s.yaml"))
    run = phc("validate", scene)
    if ok:
        assert run.returncode == 0, run.stderr
    else:
        assert run.returncode == 1
        assert run.stderr.startswith(f"{scene}:2:8: model file") and "[PHC-E116]" in run.stderr
        assert "root:" not in run.stderr  # nothing of the refused file is shown
        allowed = phc("validate", scene, "--allow-path", "/") if "passwd" not in str(layout) else None
        if allowed is not None:
            assert allowed.returncode == 0, allowed.stderr
