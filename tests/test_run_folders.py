"""Run folders are never left blocked, inputs are read bounded, secrets never printed
(issue 19): what a kill, a mistaken option or a refused value leaves, the next command
carries on from."""

from __future__ import annotations

import json
import multiprocessing
import os
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from servogym._files import MANIFEST, check_file_set, write_file_set
from servogym._input import InputError, mask_url, parse_json, read_bytes
from servogym.cli import app

TUNE = ["tune", "--chip", "MC2100", "--plant", "rotary", "--budget", "2", "--workers", "1",
        "--no-check", "--tuner", "random"]  # fmt: skip


def test_an_empty_journal_left_by_a_kill_at_start_up_is_a_new_folder(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "study.journal").write_bytes(b"")  # killed before the study was created
    result = CliRunner().invoke(app, [*TUNE, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert (out / MANIFEST).exists() and (out / "study.journal").stat().st_size > 0
    # and the finished run resumes as any other
    result = CliRunner().invoke(app, [*TUNE, "--out", str(out), "--resume"])
    assert result.exit_code == 0, result.output


def test_a_mistaken_resume_leaves_nothing_and_the_plain_command_then_runs(tmp_path):
    out = tmp_path / "new"
    result = CliRunner().invoke(app, [*TUNE, "--out", str(out), "--resume"])
    assert result.exit_code == 2 and "nothing to resume" in result.output
    assert not out.exists()
    result = CliRunner().invoke(app, [*TUNE, "--out", str(out)])
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize("option", [["--seed", "4294967296"], ["--budget", "1000000"]])
def test_an_out_of_range_value_is_refused_before_the_study_stores_anything(tmp_path, option):
    out = tmp_path / "run"
    argv = [a for a in TUNE if a not in ("--budget", "2")] + (
        ["--budget", "2"] if option[0] != "--budget" else []
    )
    result = CliRunner().invoke(app, [*argv, "--out", str(out), *option])
    assert result.exit_code == 2 and option[0] in result.output, result.output
    assert not out.exists()
    result = CliRunner().invoke(app, [*TUNE, "--out", str(out)])
    assert result.exit_code == 0, result.output


def _writer(folder: str, label: int, n: int) -> None:
    for i in range(n):
        files = {f"f{k}.txt": f"writer {label} round {i} file {k}\n" * 50 for k in range(4)}
        write_file_set(folder, files, {"trial": label * 1000 + i})


def test_two_processes_writing_sets_into_one_folder_take_turns(tmp_path):
    ctx = multiprocessing.get_context("fork")
    procs = [ctx.Process(target=_writer, args=(str(tmp_path), w, 25)) for w in (1, 2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    assert [p.exitcode for p in procs] == [0, 0]
    manifest = check_file_set(tmp_path)  # one complete set, the last writer's
    writer = manifest["trial"] // 1000
    assert all(
        (tmp_path / n).read_text().startswith(f"writer {writer} ") for n in manifest["files"]
    )
    assert not [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_a_fifo_and_a_device_are_refused_at_once(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    t = time.monotonic()
    for path, kind in ((fifo, "FIFO"), ("/dev/zero", "device"), (tmp_path, "folder")):
        with pytest.raises(InputError, match=kind):
            read_bytes(path, "--params")
    assert time.monotonic() - t < 5
    big = tmp_path / "big.json"
    big.write_bytes(b" " * 100)
    with pytest.raises(InputError, match=r"--params .*big.json' is 100 bytes; .* at most 10"):
        read_bytes(big, "--params", max_bytes=10)


def test_json_depth_is_bounded_before_parsing():
    assert parse_json("[" * 32 + "]" * 32, "x", expect=list)
    with pytest.raises(InputError, match=r"x must be JSON nested at most 32 deep"):
        parse_json("[" * 33 + "]" * 33, "x", expect=list)
    with pytest.raises(InputError, match="nested at most 32 deep"):
        parse_json("[" * 100_000 + "]" * 100_000, "x")
    assert parse_json('{"a": "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[["}', "x") == {"a": "[" * 40}
    with pytest.raises(InputError, match="appears twice"):
        parse_json('{"a": 1, "a": 2}', "x")


@pytest.mark.parametrize(
    ("url", "shown"),
    [
        ("postgresql://bob:s3cret@host:5432/db", "postgresql://bob:***@host:5432/db"),
        ("postgresql://bob:a:b@c@host/db", "postgresql://bob:***@host/db"),
        ("mysql+pymysql://u:s3cret@h/x", "mysql+pymysql://u:***@h/x"),
        ("sqlite:///runs/a@b/study.db", "sqlite:///runs/a@b/study.db"),
        ("postgresql://bob@host/db", "postgresql://bob@host/db"),
    ],
)
def test_mask_url_hides_the_whole_password(url, shown):
    assert mask_url(url) == shown


def test_the_log_never_shows_a_password(capsys):
    import logging

    from servogym.cli import setup_logging

    setup_logging(1)
    logging.getLogger("servogym.autotune").info("opening %s", "postgresql://u:s3cret@h/db")
    err = capsys.readouterr().err
    assert "u:***@h/db" in err and "s3cret" not in err
    setup_logging(0)


def test_errors_name_the_options_not_the_library_arguments():
    from servogym._cli_common import name_options

    text = (
        "min_gain_margin_db must satisfy 0 <= min_gain_margin_db <= 60; got min_gain_margin_db=-3."
    )
    assert name_options(text, {"min_gain_margin_db": "--min-gain-margin"}) == (
        "--min-gain-margin must satisfy 0 <= --min-gain-margin <= 60; got --min-gain-margin -3."
    )
    # a message that is not about the argument is left alone
    assert name_options("the motor moves", {"motor": "--axis"}) == "the motor moves"


def test_settled_needs_the_whole_steady_state_window_inside_the_band():
    from servogym.sim._metrics import METRIC_NAMES, compute_metrics

    n = 20
    commanded = np.full(n, 100, np.int64)
    actual = np.full(n, 0, np.int64)
    actual[-1] = 100  # passes through the band at the last tick only
    vals = compute_metrics(commanded, actual, np.zeros(n, np.int64), n, 2, 100, 1, 0.5, 1.0, 100)
    m = dict(zip([*METRIC_NAMES, "settled"], vals.tolist(), strict=True))
    assert m["settled"] == 0.0 and m["steady_state_error"] == 50.0
    actual[-2:] = 100  # the last tenth (2 ticks) inside the band
    vals = compute_metrics(commanded, actual, np.zeros(n, np.int64), n, 2, 100, 1, 0.5, 1.0, 100)
    assert vals[-1] == 1.0


def test_plants_prints_integers_as_integers_and_chips_filters_models():
    out = CliRunner().invoke(app, ["plants"], terminal_width=200).output
    assert "1048576" in out and "e+06" not in out
    result = CliRunner().invoke(app, ["chips", "--model", "mc2100", "--json"])
    assert result.exit_code == 0, result.output
    assert [e["model"] for e in json.loads(result.output)] == ["MC2100"]
    six = json.loads(CliRunner().invoke(app, ["chips", "--model", "6250", "--json"]).output)
    assert six[0]["export_formats"] == ["json", "6250"]  # what `export -f` takes for it


def test_a_study_left_without_its_configuration_names_the_file_to_remove(tmp_path):
    import optuna

    from servogym.autotune._session import open_storage

    out = tmp_path / "run"
    out.mkdir()
    journal = out / "study.journal"
    # killed after creating the study and before storing servogym's configuration
    optuna.create_study(storage=open_storage(str(journal)), study_name="servogym-run")
    result = CliRunner().invoke(app, [*TUNE, "--out", str(out), "--resume"])
    assert result.exit_code == 2, result.output
    line = " ".join(result.output.split())
    assert f"remove '{journal}'" in line and "without --resume" in line, line
    journal.unlink()
    (out / "study.journal.flock").unlink(missing_ok=True)
    result = CliRunner().invoke(app, [*TUNE, "--out", str(out)])
    assert result.exit_code == 0, result.output


def test_export_says_axes_not_axises():
    import tempfile
    from pathlib import Path

    from servogym.chips.pmd import PMDParams, to_json

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "p.json"
        path.write_text(to_json(PMDParams(model="MC2100")))
        result = CliRunner().invoke(app, ["export", str(path), "--axis", "9"])
    assert result.exit_code == 2
    assert "--axis must satisfy 1 <= --axis <= 4 (MC2100 has 4 axes); got --axis 9" in (
        " ".join(result.output.split())
    )
