"""A run killed while writing its outputs leaves the old set or the new one, never a mix.

A child process writes a parameter set over an older one and kills itself (SIGKILL, no
clean-up) at every step of the write in turn: after each temporary file, after the pending
manifest, after each rename. The parent then reads the folder as an engineer would.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from servogym._files import (
    MANIFEST,
    PENDING,
    FileSafetyError,
    check_file_set,
    recover_file_set,
)
from servogym.autotune._report import param_set_files, write_param_set
from servogym.chips import families, read_params_file

# A child process kills itself (SIGKILL) at step ``KILL_AT`` of servogym._files' writing:
# each temporary file written (when ``COUNT_TEMPS``) and each rename count as one step.
KILLER = textwrap.dedent(
    """
    import os, signal
    import servogym._files as F

    steps = [0]

    def step():
        steps[0] += 1
        if steps[0] == KILL_AT:
            os.kill(os.getpid(), signal.SIGKILL)

    real_temp, real_replace = F._write_temp, F.os.replace

    def temp(*a, **k):
        out = real_temp(*a, **k)
        step()
        return out

    class _Os:
        def __getattr__(self, name):
            return getattr(os, name)

        @staticmethod
        def replace(src, dst):
            real_replace(src, dst)
            step()

    F.os = _Os()
    if COUNT_TEMPS:
        F._write_temp = temp
    """
)

CHILD = (
    textwrap.dedent(
        """
    import sys
    KILL_AT, COUNT_TEMPS = int(sys.argv[1]), True
    """
    )
    + KILLER
    + textwrap.dedent(
        """
    from servogym.autotune._report import write_param_set
    from servogym.chips import get_chip

    folder, model, kp_name, kp = sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5])
    family, model = get_chip(model)
    params = family.make_params(model, {kp_name: kp})
    write_param_set(params, folder, trial=2, extra_files={"summary.json": "{}\\n"})
    print(steps[0])
    """
    )
)

GAIN = {"pmd": "kp", "pmac": "proportional_gain", "parker6k": "sgp"}


def _run_child(kill_at: int, folder: Path, model: str, name: str, value: int):
    return subprocess.run(
        [sys.executable, "-c", CHILD, str(kill_at), str(folder), model, name, str(value)],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize(
    "family_name", ["pmd", pytest.param("pmac", marks=pytest.mark.slow),
                    pytest.param("parker6k", marks=pytest.mark.slow)],
)  # fmt: skip
def test_killed_at_every_step_the_folder_holds_one_set(tmp_path, family_name):
    family = families()[family_name]
    model = next(m for m in family.models if len(family.formats_for(m)) == len(family.formats))
    name = GAIN[family_name]
    old = family.make_params(model, {name: 101})
    new = family.make_params(model, {name: 202})
    old_files = param_set_files(old)

    # How many steps a complete write takes (the child kills itself at none).
    probe = tmp_path / "probe"
    probe.mkdir()
    done = _run_child(0, probe, model, name, 202)
    assert done.returncode == 0, done.stderr
    n_steps = int(done.stdout.strip())
    assert read_params_file(probe / "best_params.json").params == new
    n_files = len(old_files) + 1  # with summary.json
    assert n_steps == 2 * n_files + 3  # temps, pending (temp + rename), renames, commit

    outcomes = {"old": 0, "rolled forward": 0}
    for kill_at in range(1, n_steps):  # the last step commits: after it the new set is whole
        folder = tmp_path / f"k{kill_at}"
        folder.mkdir()
        write_param_set(old, folder, trial=1, extra_files={"summary.json": "{}\n"})
        res = _run_child(kill_at, folder, model, name, 202)
        assert res.returncode == -9, (kill_at, res.stderr)
        if not (folder / PENDING).exists():
            # Killed before the intent was recorded: the old set, whole, untouched.
            assert check_file_set(folder)["trial"] == 1
            for n in old_files:  # every file: the manifest's hash, and the old set inside
                assert read_params_file(folder / n).params == old, n
            outcomes["old"] += 1
        else:
            # Killed after it: readers refuse every file of the set until it is completed.
            with pytest.raises(FileSafetyError, match="being replaced"):
                check_file_set(folder)
            with pytest.raises(FileSafetyError, match="being replaced"):
                read_params_file(folder / next(iter(old_files)))
            assert recover_file_set(folder) == "rolled forward"
            assert check_file_set(folder)["trial"] == 2
            for n in old_files:
                assert read_params_file(folder / n).params == new, n
            outcomes["rolled forward"] += 1
        recover_file_set(folder)  # removes the temporary files a kill left
        assert not [p.name for p in folder.iterdir() if p.name.endswith(".tmp")]
        assert json.loads((folder / MANIFEST).read_text())["files"].keys() == {
            *old_files,
            "summary.json",
        }
    assert outcomes["old"] > 0 and outcomes["rolled forward"] > 0


def test_a_file_edited_after_the_run_is_refused_by_the_loader(tmp_path):
    family = families()["pmd"]
    params = family.make_params("MC2100", {"kp": 300})
    write_param_set(params, tmp_path, trial=5)
    for path in tmp_path.glob("best_params*"):
        assert read_params_file(path).params == params
    # Another set's file dropped into the folder: the manifest tells.
    other = param_set_files(family.make_params("MC2100", {"kp": 9}))["best_params.c"]
    (tmp_path / "best_params.c").write_text(other)
    with pytest.raises(FileSafetyError, match=r"best_params\.c does not match manifest\.json"):
        read_params_file(tmp_path / "best_params.c")
    assert read_params_file(tmp_path / "best_params.json").params == params


TUNE_CHILD = (
    textwrap.dedent(
        """
    import sys
    KILL_AT, COUNT_TEMPS = int(sys.argv[1]), False
    """
    )
    + KILLER
    + textwrap.dedent(
        """
    from pathlib import Path
    from servogym.autotune import TuneConfig, tune
    from servogym.sim import MoveSpec

    out, budget = Path(sys.argv[2]), int(sys.argv[3])
    moves = (MoveSpec(1.0, 40.0, 3000.0, 0.03), MoveSpec(-1.0, 40.0, 3000.0, 0.03))
    config = TuneConfig(chip="MC2100", plant="rotary", out=out, budget=budget, tuner="random",
                        workers=1, moves=moves, batch_size=2, resume=budget > 2)
    tune(config)
    """
    )
)


@pytest.mark.slow
def test_a_real_tune_killed_between_renames_is_completed_by_resume(tmp_path):
    run = lambda kill_at, budget: subprocess.run(  # noqa: E731
        [sys.executable, "-c", TUNE_CHILD, str(kill_at), str(tmp_path), str(budget)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    first = run(0, 2)
    assert first.returncode == 0, first.stderr
    old = check_file_set(tmp_path)
    killed = run(4, 6)  # renames: the pending manifest, then 3 of the set's files
    assert killed.returncode == -9, killed.stderr
    with pytest.raises(FileSafetyError, match="being replaced"):
        read_params_file(tmp_path / "best_params.json")
    again = run(0, 6)  # the same command with --resume finishes the set, then rewrites it
    assert again.returncode == 0, again.stderr
    new = check_file_set(tmp_path)
    assert new["trial"] is not None and new["token"] != old["token"]
    assert json.loads((tmp_path / "summary.json").read_text())["n_trials"] == 6
