"""Every command against a corpus of bad inputs: a non-zero exit, one line naming the
parameter and the value, never a traceback (issue 11).

Each case is ``(args, parameter, value)``: the error line must contain both strings.
``{d}`` in an argument is the folder of the fixture files below. The corpus is a table so
a new option gets its bad values by adding rows; the count is asserted (>= 200).
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
from typer.testing import CliRunner

from servogym.chips.pmac import PMACParams
from servogym.chips.pmac import to_ivar as pmac_ivar
from servogym.chips.pmd import PMDParams, to_json
from servogym.chips.pmd._export import to_cmotion
from servogym.cli import app

TUNE = ["tune", "--chip", "MC2100", "--plant", "rotary", "--budget", "3", "--out"]
SIM = ["simulate", "--out", "{d}/sim"]
ENV = "servogym/Tune-PMD-Rotary-v0"
BENCH = ["benchmark", "--out", "{d}/bench", "--dry-run"]

BAD_INT = [("x", "'x'"), ("1.5", "'1.5'"), ("nan", "'nan'"), ("", "''")]
BAD_FLOAT = [("x", "'x'"), ("nan", "nan"), ("inf", "inf"), ("-inf", "-inf")]


def _cases() -> list[tuple[list[str], str, str]]:
    c: list[tuple[list[str], str, str]] = []
    # ---------------------------------------------------------------- tune
    tune = [*TUNE, "{d}/run"]
    for opt in ("--budget", "--workers", "--robust", "--batch-size", "--seed"):
        base = [a for a in tune]
        if opt == "--budget":
            base = [a for a in tune if a not in ("--budget", "3")]
        for value, shown in BAD_INT:
            c.append(([*base, opt, value], opt, shown))
        if opt != "--seed":
            c.append(([*base, opt, "0"], opt, "0"))
        c.append(([*base, opt, "-2"], opt, "-2"))
    for value, shown in [*BAD_FLOAT, ("0", "0"), ("-5", "-5")]:
        c.append(([*tune, "--max-following-error", value], "--max-following-error", shown))
    for value, shown in [*BAD_FLOAT, ("-0.1", "-0.1"), ("1.5", "1.5")]:
        c.append(([*tune, "--max-saturation", value], "--max-saturation", shown))
    c += [
        ([*TUNE[:2], "MC9999", *TUNE[3:], "{d}/run"], "chip model", "MC9999"),
        ([*TUNE[:2], "", *TUNE[3:], "{d}/run"], "chip model", "''"),
        ([*TUNE[:4], "rotry", *TUNE[5:], "{d}/run"], "plant", "rotry"),
        ([*TUNE[:4], "", *TUNE[5:], "{d}/run"], "plant", "''"),
        ([*tune, "--tuner", "tpee"], "tuner", "tpee"),
        ([*tune, "--tuner", ""], "tuner", "''"),
        ([*tune, "--robust-mode", "median"], "--robust-mode", "median"),
        ([*tune, "--plant-param", "payload_kg"], "--plant-param", "payload_kg"),
        ([*tune, "--plant-param", "payload_kg=heavy"], "--plant-param", "heavy"),
        ([*tune, "--plant-param", "nosuch=1"], "nosuch", "nosuch"),
        ([*tune, "--plant-param", "load_inertia_kgm2=-1"], "load_inertia_kgm2", "-1"),
        ([*tune, "--plant-param", "load_inertia_kgm2=nan"], "load_inertia_kgm2", "nan"),
        ([*tune, "--plant-param", "load_inertia_kgm2=inf"], "load_inertia_kgm2", "inf"),
        ([*tune, "--fix", "kp"], "--fix", "kp"),
        ([*tune, "--fix", "kp=1.5"], "--fix", "1.5"),
        ([*tune, "--fix", "kp=-1"], "kp", "-1"),
        ([*tune, "--fix", "kp=99999999"], "kp", "99999999"),
        ([*tune, "--fix", "kpp=1"], "kpp", "kpp"),
        ([*tune, "--fix", "kp=nan"], "--fix", "nan"),
        ([*tune, "--search", "kpp"], "kpp", "kpp"),
        ([*tune, "--warm-start", "{d}/missing.json"], "--warm-start", "missing.json"),
        ([*tune, "--warm-start", "{d}"], "--warm-start", "'{d}'"),
        ([*tune, "--warm-start", "{d}/corrupt.json"], "--warm-start", "corrupt.json"),
        ([*tune, "--warm-start", "{d}/empty.txt"], "--warm-start", "empty.txt"),
        ([*tune, "--warm-start", "{d}/binary.bin"], "--warm-start", "binary.bin"),
        ([*tune, "--warm-start", "{d}/pmac.pmc"], "--warm-start", "pmac.pmc"),
        ([*tune, "--warm-start", "{d}/dup.json"], "--warm-start", "'kp'"),
        ([*tune, "--warm-start", "{d}/truncated.c"], "--warm-start", "truncated.c"),
        ([*tune, "--storage", "nosuchdb://x"], "--storage", "nosuchdb://x"),
        # (a plain path is a journal file, created if missing: "not a url" is legal)
        ([*tune, "--storage", "{d}"], "--storage", "is a folder"),
        ([*tune, "--storage", "{d}/corrupt.json"], "--storage", "not an Optuna journal file"),
        ([*tune, "--storage", "{d}/binary.bin"], "--storage", "not an Optuna journal file"),
        ([*TUNE, "{d}/afile.txt"], "--out", "afile.txt"),
        ([*TUNE, "{d}/done"], "--out", "done"),
        ([*TUNE, "{d}/corruptdb", "--resume"], "--storage", "study.db"),
        ([*TUNE, "{d}/fresh", "--resume"], "resume", "servogym-fresh"),
    ]
    # ---------------------------------------------------------------- simulate
    for value, shown in [("x", "'x'"), ("0", "0"), ("-1", "-1"), ("1.5", "'1.5'")]:
        c.append(([*SIM, "--substeps", value], "--substeps", shown))
    c += [
        ([*SIM, "--chip", "MC9999"], "chip model", "MC9999"),
        ([*SIM, "--plant", "rotry"], "plant", "rotry"),
        ([*SIM, "--plant-param", "load_inertia_kgm2=0"], "load_inertia_kgm2", "0"),
        ([*SIM, "--plant-param", "load_inertia_kgm2=nan"], "load_inertia_kgm2", "nan"),
        ([*SIM, "--plant-param", "load_inertia_kgm2=inf"], "load_inertia_kgm2", "inf"),
        ([*SIM, "--plant-param", "inertia_kgm2"], "--plant-param", "inertia_kgm2"),
        ([*SIM, "--plant-param", "x=1"], "x", "x"),
        ([*SIM, "--params", "{d}/missing.json"], "--params", "missing.json"),
        ([*SIM, "--params", "{d}/corrupt.json"], "--params", "corrupt.json"),
        ([*SIM, "--params", "{d}/dup.json"], "--params", "'kp'"),
        ([*SIM, "--params", "{d}/nan.json"], "--params", "NaN"),
        ([*SIM, "--params", "{d}/truncated.c"], "--params", "truncated.c"),
        ([*SIM, "--params", "{d}/edited.c"], "--params", "edited.c"),
        ([*SIM, "--params", "{d}/ifzero.c"], "--params", "#if 0"),
        ([*SIM, "--params", "{d}/empty.txt"], "--params", "empty.txt"),
        ([*SIM, "--params", "{d}/binary.bin"], "--params", "binary.bin"),
        ([*SIM, "--params", "{d}/words.txt"], "--params", "words.txt"),
        ([*SIM, "--params", "{d}/noheader.pmc"], "--params", "noheader.pmc"),
        ([*SIM, "--params", "{d}/tiny.pmc"], "--params", "1e-9"),
        ([*SIM, "--params", "{d}/p.json", "--chip", "MC2300"], "--chip", "MC2300"),
        ([*SIM, "--params", "{d}/p.json", "--chip", "TurboPMAC2"], "--chip", "TurboPMAC2"),
        ([*SIM, "--params", "{d}/p.json", "--format", "pdf"], "--format", "'pdf'"),
        ([*SIM, "--params", "{d}/p.json", "--format", "ivar"], "--params", "p.json"),
        (["simulate", "--out", "{d}/afile.txt"], "--out", "afile.txt"),
    ]
    for move, shown in [
        ("1,2", "'1,2'"), ("1,2,3,4,5", "'1,2,3,4,5'"), ("a,2,3", "'a'"), ("nan,1,10", "'nan'"),
        ("1,inf,10", "'inf'"), ("1,-1,10", "-1"), ("1,0,10", "0"), ("1,1,0", "0"),
        ("1,1,-5", "-5"), ("1,1,10,-1", "-1"), ("1,1,10,nan", "'nan'"), ("", "''"),
    ]:  # fmt: skip
        c.append(([*SIM, "--move", move], "--move", shown))
    # ---------------------------------------------------------------- export
    exp = ["export", "{d}/p.json"]
    c += [
        (["export", "{d}/missing.json"], "PARAMS_FILE", "missing.json"),
        (["export", "{d}"], "PARAMS_FILE", "'{d}'"),
        (["export", "{d}/corrupt.json"], "PARAMS_FILE", "corrupt.json"),
        (["export", "{d}/dup.json"], "PARAMS_FILE", "'kp'"),
        (["export", "{d}/nan.json"], "PARAMS_FILE", "NaN"),
        (["export", "{d}/wrongfamily.json"], "chip_family", "'nope'"),
        (["export", "{d}/truncated.c"], "PARAMS_FILE", "cut short"),
        (["export", "{d}/edited.c"], "PARAMS_FILE", "checksum"),
        (["export", "{d}/ifzero.c"], "PARAMS_FILE", "#if 0"),
        (["export", "{d}/empty.txt"], "PARAMS_FILE", "empty.txt"),
        (["export", "{d}/binary.bin"], "PARAMS_FILE", "binary.bin"),
        (["export", "{d}/words.txt"], "PARAMS_FILE", "words.txt"),
        (["export", "{d}/noheader.pmc"], "PARAMS_FILE", "model"),
        (["export", "{d}/tiny.pmc"], "PARAMS_FILE", "1e-9"),
        (["export", "{d}/parker_missing_gain.prg"], "PARAMS_FILE", "SGI"),
        (["export", "{d}/torn/best_params.c"], "PARAMS_FILE", "manifest.json"),
        ([*exp, "--format", "pdf"], "--format", "'pdf'"),
        ([*exp, "--format", "ivar"], "--format", "'ivar'"),
        ([*exp, "--format", ""], "--format", "''"),
        ([*exp, "--input-format", "pdf"], "--input-format", "'pdf'"),
        ([*exp, "--input-format", "cmotion"], "PARAMS_FILE", "p.json"),
        ([*exp, "--chip", "MC9999"], "chip model", "MC9999"),
        ([*exp, "--chip", "MC2300"], "--chip", "MC2300"),
        ([*exp, "--axis", "0"], "axis", "0"),
        ([*exp, "--axis", "-1"], "axis", "-1"),
        ([*exp, "--axis", "9"], "axis", "9"),
        ([*exp, "--axis", "x"], "--axis", "'x'"),
        ([*exp, "--out", "{d}/p.json"], "--out", "p.json"),
        ([*exp, "--out", "{d}/p.json", "--force"], "--out", "p.json"),
        ([*exp, "--out", "{d}/existing.c"], "--out", "existing.c"),
        ([*exp, "--out", "{d}"], "--out", "'{d}'"),
        ([*exp, "--out", "{d}/nosuchdir/x.c"], "--out", "nosuchdir"),
    ]
    # ---------------------------------------------------------------- train
    train = ["train", "--env", ENV, "--out", "{d}/train"]
    for opt in ("--timesteps", "--n-envs", "--checkpoint-every", "--seed"):
        for value, shown in BAD_INT:
            c.append(([*train, opt, value], opt, shown))
        if opt != "--seed":
            c.append(([*train, opt, "0"], opt, "0"))
        c.append(([*train, opt, "-1"], opt, "-1"))
    for value, shown in [*BAD_FLOAT, ("-1", "-1"), ("0", "0")]:
        c.append(([*train, "--minutes", value], "--minutes", shown))
    c += [
        (["train", "--env", "servogym/Tune-PMD-Rotry-v0"], "env id", "Rotry"),
        (["train", "--env", ""], "env id", "''"),
        ([*train, "--algo", "dqn"], "--algo", "'dqn'"),
        ([*train, "--env-kwargs", "{"], "--env-kwargs", "'{'"),
        ([*train, "--env-kwargs", "[1]"], "--env-kwargs", "'[1]'"),
        ([*train, "--env-kwargs", '{"bogus": 1}'], "--env-kwargs", "bogus"),
        ([*train, "--env-kwargs", '{"chip_model": "MC9999"}'], "--env-kwargs", "MC9999"),
        ([*train, "--algo-kwargs", "{"], "--algo-kwargs", "'{'"),
        ([*train, "--algo-kwargs", '{"bogus": 1}'], "--algo-kwargs", "bogus"),
        ([*train, "--algo-kwargs", "[1]"], "--algo-kwargs", "'[1]'"),
        (["train", "--env", ENV, "--out", "{d}/afile.txt"], "--out", "afile.txt"),
    ]
    # ---------------------------------------------------------------- evaluate
    ev = ["evaluate", "--env", ENV, "--episodes", "1"]
    for opt in ("--episodes", "--seed"):
        base = ["evaluate", "--env", ENV] if opt == "--episodes" else ev
        for value, shown in BAD_INT:
            c.append(([*base, opt, value], opt, shown))
        if opt == "--episodes":
            c.append(([*base, opt, "0"], opt, "0"))
        c.append(([*base, opt, "-1"], opt, "-1"))
    c += [
        (["evaluate"], "--env", "--model"),
        (["evaluate", "--env", "servogym/Nope-v0"], "env id", "Nope"),
        ([*ev, "--model", "{d}/missing.zip"], "--model", "missing.zip"),
        ([*ev, "--model", "{d}/corrupt.json"], "--model", "corrupt.json"),
        ([*ev, "--model", "{d}/model/model.zip"], "--model", "model.zip"),
        ([*ev, "--model", "{d}/badcfg/model.zip"], "--model", "model.zip"),
        ([*ev, "--env-kwargs", "{"], "--env-kwargs", "'{'"),
        ([*ev, "--env-kwargs", '{"bogus": 1}'], "--env-kwargs", "bogus"),
        (
            [*ev, "--env-kwargs", '{"plant_values": {"load_inertia_kgm2": -1}}'],
            "load_inertia_kgm2",
            "-1",
        ),
        ([*ev, "--fixed", "{d}/missing.json"], "--fixed", "missing.json"),
        ([*ev, "--fixed", "{d}/corrupt.json"], "--fixed", "corrupt.json"),
        ([*ev, "--fixed", "{d}/dup.json"], "--fixed", "'kp'"),
        ([*ev, "--fixed", "{d}/nan.json"], "--fixed", "NaN"),
        ([*ev, "--fixed", "{d}/regs_bad.json"], "--fixed", "kpp"),
        ([*ev, "--fixed", "{d}/regs_range.json"], "--fixed", "-5"),
        ([*ev, "--fixed", "{d}/regs_list.json"], "--fixed", "list"),
        ([*ev, "--fixed", "{d}/pmac.pmc"], "--fixed", "TurboPMAC2"),
        ([*ev, "--fixed", "{d}/truncated.c"], "--fixed", "cut short"),
    ]
    # ---------------------------------------------------------------- benchmark
    for opt in ("--seeds", "--workers"):
        for value, shown in BAD_INT:
            c.append(([*BENCH, opt, value], opt, shown))
        c.append(([*BENCH, opt, "0"], opt, "0"))
        c.append(([*BENCH, opt, "-2"], opt, "-2"))
    for value, shown in [("0", "'0'"), ("x", "'x'"), ("-5", "'-5'"), ("", "''"), ("1.5", "'1.5'")]:
        c.append(([*BENCH, "--budget", value], "--budget", shown))
    c += [
        ([*BENCH, "--suite", "nope"], "suite", "nope"),
        ([*BENCH, "--split", "nope"], "split", "nope"),
        ([*BENCH, "--tuners", "nope"], "tuner", "nope"),
        ([*BENCH, "--tuners", ""], "--tuners", "''"),
        ([*BENCH, "--instance", "nope"], "instance", "nope"),
        ([*BENCH, "--limit", "gp:seeds=x"], "--limit", "gp:seeds=x"),
        ([*BENCH, "--limit", "nope"], "--limit", "nope"),
        (["benchmark", "--out", "{d}/afile.txt", "--dry-run"], "--out", "afile.txt"),
    ]
    # ---------------------------------------------------------------- top level
    c += [
        (["nocommand"], "command", "nocommand"),
        (["chips", "--bogus"], "--bogus", "--bogus"),
        (["plants", "--bogus"], "--bogus", "--bogus"),
        (["tune"], "--chip", "--chip"),
    ]
    return c


CASES = _cases()


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("bad")
    p = PMDParams(model="MC2100", kp=300)
    (d / "p.json").write_text(to_json(p))
    (d / "existing.c").write_text("keep me\n")
    (d / "afile.txt").write_text("a file, not a folder\n")
    (d / "corrupt.json").write_text('{"format": "servogym-params", "params": {')
    (d / "empty.txt").write_text("")
    (d / "binary.bin").write_bytes(b"\x00\xff\xfe\x80" * 10)
    (d / "words.txt").write_text("hello world\n")
    doc = json.loads(to_json(p))
    del doc["checksum"]
    text = json.dumps(doc, indent=2)
    (d / "dup.json").write_text(text.replace('"kp": 300', '"kp": 100, "kp": 32000'))
    (d / "nan.json").write_text(text.replace('"kp": 300', '"kp": NaN'))
    wrong = text.replace('"chip_family": "pmd"', '"chip_family": "nope"')
    (d / "wrongfamily.json").write_text(wrong)
    c_text = to_cmotion(p)
    (d / "truncated.c").write_text(c_text[: c_text.index("PMDUpdate")])
    (d / "edited.c").write_text(c_text.replace("PMDSetKp(&hAxis1, 300)", "PMDSetKp(&hAxis1, 301)"))
    hand = "".join(
        line + "\n" for line in c_text.splitlines()
        if "parameter set" not in line and "servogym-end" not in line
    )  # fmt: skip
    (d / "ifzero.c").write_text(hand + "#if 0\nPMDSetKp(&hAxis1, 9);\n#endif\n")
    ivar = pmac_ivar(PMACParams(model="TurboPMAC2"))
    (d / "pmac.pmc").write_text(ivar)
    body = [line for line in ivar.splitlines() if not line.startswith(";")]
    (d / "noheader.pmc").write_text("\n".join(body) + "\n")
    (d / "tiny.pmc").write_text(
        "\n".join(b.replace("I136=0 ", "I136=1e-9 ") for b in body) + "\n; chip_model: TurboPMAC2\n"
    )
    (d / "parker_missing_gain.prg").write_text(
        "; chip_model: 6250\nSSFR4\nSGP85\nSGI0\nSGV2.3\nSGVF0\nSGAF0\nSGSET1\nSGP9\nSGSET2\n"
        "SGP85\nSGI0\nSGV2.3\nSGVF0\nSGAF0\nSGILIM10\nSOFFS0\nSMPER0\n"
    )
    (d / "regs_bad.json").write_text('{"kpp": 1}')
    (d / "regs_range.json").write_text('{"kp": -5}')
    (d / "regs_list.json").write_text('{"kp": [1, 2]}')
    # A tune folder whose set is torn (another run's export dropped in).
    from servogym.autotune._report import param_set_files, write_param_set

    (d / "torn").mkdir()
    write_param_set(p, d / "torn", trial=1)
    other = param_set_files(PMDParams(model="MC2100", kp=9))["best_params.c"]
    (d / "torn" / "best_params.c").write_text(other)
    # A finished run folder, a corrupt study.db, a model run folder without weights.
    (d / "done").mkdir()
    write_param_set(p, d / "done", trial=1)
    (d / "corruptdb").mkdir()
    (d / "corruptdb" / "study.db").write_bytes(b"this is not a database" * 100)
    with pytest.raises(sqlite3.DatabaseError):
        sqlite3.connect(d / "corruptdb" / "study.db").execute("select 1 from sqlite_master")
    for name, cfg in (("model", {"env_id": ENV, "algo": "ppo"}), ("badcfg", "{")):
        (d / name).mkdir()
        (d / name / "config.json").write_text(cfg if isinstance(cfg, str) else json.dumps(cfg))
        (d / name / "model.zip").write_bytes(b"PK\x05\x06" + b"\x00" * 18)  # an empty zip
    return d


def test_the_corpus_is_large_and_covers_every_command():
    assert len(CASES) >= 200
    commands = {args[0] for args, _, _ in CASES}
    assert {"tune", "simulate", "export", "train", "evaluate", "benchmark", "chips"} <= commands


@pytest.mark.parametrize(("args", "parameter", "value"), CASES, ids=lambda x: None)
def test_bad_input_gives_one_line_naming_parameter_and_value(files, args, parameter, value):
    argv = [a.replace("{d}", str(files)) for a in args]
    value = value.replace("{d}", str(files))
    result = CliRunner().invoke(app, argv)
    out = result.output
    assert result.exit_code not in (0, None), (argv, out)
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        argv,
        repr(result.exception),
    )
    assert "Traceback" not in out, out
    errors = [line for line in out.splitlines() if line.lower().startswith("error:")]
    assert len(errors) == 1, (argv, out)
    others = [
        line for line in out.splitlines()
        if line.strip() and line not in errors and not line.startswith(("Usage:", "Try '"))
    ]  # fmt: skip
    assert not others, (argv, out)
    assert parameter in errors[0] and value in errors[0], (argv, errors[0])
