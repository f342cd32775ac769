"""The generated bad-input suite (issue 19): every command x option class x file damage.

Where ``tests/test_cli_bad_input.py`` is a hand table of named cases, this suite generates
its cases from registries: the commands and their options come from the typer app (an
integer option gets the integer damage, a JSON-text option the JSON damage, ...), the
file-reading options from :data:`FILE_INPUTS` crossed with every damage in
:data:`FILE_DAMAGE`, the env contradictions from Gymnasium's registry. Every case asserts:

* exit code 2 (click's usage errors and servogym's one-line errors alike);
* exactly one ``error:`` line, naming the option (or keyword) and the value;
* no traceback, no exception other than ``SystemExit``;
* no secret (the password of a database URL) anywhere in the output;
* nothing written: the case's fresh output folder stays empty, the input files unchanged.

Hangs (``/dev/zero``, a FIFO) would stop the suite: every case runs under a 60 s alarm.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
from pathlib import Path

import gymnasium as gym
import pytest
import typer
from typer.testing import CliRunner

import servogym  # noqa: F401  (registers the env ids)
from servogym.chips.pmd import PMDParams, to_json
from servogym.cli import app

ENV = "servogym/Tune-PMD-Rotary-v0"
SECRET = "s3cret"
DEEP = "[" * 5000 + "]" * 5000
TUNE = ["tune", "--chip", "MC2100", "--plant", "rotary", "--budget", "3", "--out", "{o}/run"]
COMMANDS = typer.main.get_command(app).commands

# ------------------------------------------------------------------------------ files

FILE_INPUTS: dict[str, list[str]] = {
    "PARAMS_FILE": ["export", "{f}"],
    "--params": ["simulate", "--params", "{f}", "--out", "{o}/sim"],
    "PARAMS": ["check", "{f}", "--plant", "rotary", "--out", "{o}/chk"],
    "--warm-start": [*TUNE, "--warm-start", "{f}"],
    "--fixed": ["evaluate", "--env", ENV, "--episodes", "1", "--fixed", "{f}"],
}
"""Option (as its errors name it) -> a command line reading the file ``{f}``."""

FILE_DAMAGE = {
    "missing": "missing.json",
    "a folder": "folder",
    "/dev/zero": "/dev/zero",
    "a FIFO": "fifo",
    "empty": "empty.json",
    "binary": "binary.bin",
    "deep JSON": "deep.json",
    "deep JSON in an object": "deep_obj.json",
    "too large": "huge.json",
    "a JSON array": "array.json",
    "a JSON string": "string.json",
    "cut JSON": "cut.json",
    "a key twice": "dup.json",
    "NaN": "nan.json",
    "deep manifest.json beside it": "mdeep/p.json",
    "manifest.json a list": "mlist/p.json",
    "manifest.json with string entries": "mstr/p.json",
    "manifest.json garbage": "mgarbage/p.json",
}
"""Damage -> the damaged file (relative to the fixture folder, or absolute)."""


def _file_cases() -> list[tuple[list[str], str, str]]:
    cases = []
    for option, argv in FILE_INPUTS.items():
        for damage, name in FILE_DAMAGE.items():
            if option == "--fixed" and damage.startswith(("a JSON array",)):
                continue  # --fixed takes a register object or a parameter file: covered below
            path = name if name.startswith("/") else "{d}/" + name
            shown = "manifest" if "manifest" in damage else name.rsplit("/", 1)[-1]
            cases.append(([a.replace("{f}", path) for a in argv], option, shown))
    return cases


# ------------------------------------------------------------------------------ options

INT_DAMAGE = [("x", "'x'"), ("1.5", "'1.5'"), ("", "''"), ("-1", "-1"),
              ("1" + "0" * 30, "1" + "0" * 30)]  # fmt: skip
FLOAT_DAMAGE = [("x", "'x'"), ("nan", "nan"), ("inf", "inf"), ("1e999", "inf"),
                ("-1e308", "-1e+308")]  # fmt: skip
NAME_DAMAGE = [("", "''"), ("nosuch", "'nosuch'")]

NAME_OPTIONS = {
    ("tune", "--chip"), ("tune", "--plant"), ("tune", "--tuner"), ("tune", "--robust-mode"),
    ("simulate", "--chip"), ("simulate", "--plant"), ("check", "--plant"), ("check", "--chip"),
    ("export", "--chip"), ("export", "--format"), ("export", "--input-format"),
    ("train", "--algo"), ("train", "--env"), ("evaluate", "--env"),
    ("benchmark", "--suite"), ("benchmark", "--split"), ("benchmark", "--tuners"),
}  # fmt: skip
"""Options naming something from a registry (chip models, plants, tuners, formats, ids)."""
JSON_DAMAGE = [
    (DEEP, "nested"),
    ("[1]", "array"),
    ('"x"', "string"),
    ("{", "invalid JSON"),
    ('{"a": 1, "a": 2}', "twice"),
    ('{"a": NaN}', "NaN"),
]

BASE = {
    "tune": TUNE,
    "simulate": ["simulate", "--out", "{o}/sim"],
    "check": ["check", "{d}/p.json", "--plant", "rotary", "--out", "{o}/chk"],
    "export": ["export", "{d}/p.json"],
    "train": ["train", "--env", ENV, "--out", "{o}/train"],
    "evaluate": ["evaluate", "--env", ENV, "--episodes", "1"],
    "benchmark": ["benchmark", "--out", "{o}/bench", "--dry-run", "--tuners", "tpe"],
}
"""Command -> a good command line its bad option values are added to."""

JSON_OPTIONS = {("train", "--env-kwargs"), ("train", "--algo-kwargs"), ("evaluate", "--env-kwargs")}


def _kind(param) -> str:
    """``"int"``, ``"float"`` or ``""`` from the option's annotation (``int | None`` is int)."""
    import typing

    annotation = param.type_descriptor.annotation
    kinds = {annotation, *typing.get_args(annotation)}
    return "int" if int in kinds else "float" if float in kinds else ""


def _drop(argv: list[str], opt: str) -> list[str]:
    """``argv`` without ``opt`` and its value (so the bad value is the only one)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
            continue
        if a == opt:
            skip = True
            continue
        out.append(a)
    return out


def _option_cases() -> list[tuple[list[str], str, str]]:
    cases = []
    for command, base in BASE.items():
        for param in COMMANDS[command].params:
            opts = [o for o in param.opts if o.startswith("--")]
            if not opts or getattr(param, "is_flag", False) or param.count:
                continue
            opt = opts[0]
            kind = _kind(param)
            argv = _drop(base, opt)
            if kind == "int":
                for value, shown in INT_DAMAGE:
                    cases.append(([*argv, opt, value], opt, shown))
            elif kind == "float":
                for value, shown in FLOAT_DAMAGE:
                    cases.append(([*argv, opt, value], opt, shown))
            elif (command, opt) in JSON_OPTIONS:
                for value, shown in JSON_DAMAGE:
                    cases.append(([*argv, opt, value], opt, shown))
            elif (command, opt) in NAME_OPTIONS:
                for value, shown in NAME_DAMAGE:
                    cases.append(([*argv, opt, value], opt, shown))
    return cases


# ------------------------------------------------------------------------------ contradictions

CONTRADICTIONS: list[tuple[list[str], str, str]] = [
    (["simulate", "--substeps", "3", "--reference", "--out", "{o}/s"], "--substeps", "--reference"),
    (["simulate", "--format", "json", "--out", "{o}/s"], "--format", "--params"),
    (["simulate", "--chip", "", "--out", "{o}/s"], "chip model", "''"),
    (["simulate", "--move", "0.3,1e300,1e300", "--out", "{o}/s"], "--move", "1e+300"),
    (["simulate", "--move", "1e300,1,1", "--out", "{o}/s"], "--move", "1e+300"),
    (["simulate", "--move", "0.3,1,1,1e300", "--out", "{o}/s"], "--move", "1e+300"),
    (["simulate", "--out", "{d}/p.json/sub"], "--out", "p.json"),
    (["simulate", "--plant-param", "payload_kg=1", "--plant-param", "payload_kg=2",
      "--out", "{o}/s"], "--plant-param", "payload_kg"),
    (["export", "{d}/p6250.prg", "-f", "6k"], "--format", "'6k'"),
    (["export", "{d}/p.json", "-f", "pdf"], "--format", "'pdf'"),
    (["check", "{d}/p.json", "--plant", "rotary", "--min-gain-margin", "-3", "--out", "{o}/c"],
     "--min-gain-margin", "-3"),
    (["check", "{d}/p.json", "--plant", "rotary", "--out", "{d}/p.json/sub"], "--out", "p.json"),
    ([*TUNE, "--fix", "kp=1", "--fix", "kp=2"], "--fix", "kp"),
    ([*TUNE, "--plant-param", "payload_kg=1", "--plant-param", "payload_kg=2"],
     "--plant-param", "payload_kg"),
    ([*TUNE, "--study-name", ""], "--study-name", "''"),
    ([*TUNE, "--study-name", " x"], "--study-name", "' x'"),
    ([*TUNE, "--storage", "::::"], "--storage", "'::::'"),
    ([*TUNE, "--storage", ""], "--storage", "''"),
    ([*TUNE, "--resume"], "--resume", "nothing to resume"),
    ([*TUNE, "--resume", "--storage", "{o}/s.journal"], "--resume", "s.journal"),
    ([*TUNE, "--resume", "--storage", "sqlite:///{o}/s.db"], "--resume", "s.db"),
    ([*_drop(TUNE, "--budget"), "--budget", "1000000000"], "--budget", "1000000000"),
    ([*TUNE, "--seed", "4294967296"], "--seed", "4294967296"),
    ([*TUNE, "--storage", "{d}/fifo"], "--storage", "FIFO"),
    ([*TUNE, "--storage", "/dev/zero"], "--storage", "/dev/zero"),
    ([*TUNE, "--storage", "{d}/deep.json"], "--storage", "deep.json"),
    ([*TUNE, "--storage", f"postgresql://u:{SECRET}@127.0.0.1:1/db"], "--storage", "u:***@"),
    ([*TUNE, "--storage", f"mysql+pymysql://u:{SECRET}@127.0.0.1:1/db"], "--storage", "u:***@"),
    ([*TUNE, "--storage", f"postgresql://u:a:{SECRET}@x@127.0.0.1:1/db"], "--storage", "u:***@"),
    ([*BASE["benchmark"][:-2], "--tuners", "tpe,tpe"], "--tuners", "tpe"),
    ([*BASE["benchmark"], "--limit", "cmaes:seeds=1"], "--limit", "cmaes"),
    ([*BASE["benchmark"], "--limit", "tpe:seeds=0"], "--limit", "seeds=0"),
    ([*BASE["benchmark"], "--limit", "tpe:seeds=1", "--limit", "tpe:budget=5"], "--limit", "tpe"),
    ([*BASE["benchmark"], "--budget", "20,20"], "--budget", "20,20"),
    ([*BASE["benchmark"], "--budget", "100000000"], "--budget", "100000000"),
    ([*BASE["benchmark"], "--split", "heldout", "--instance", "{train_id}"], "--instance",
     "{train_id}"),
    ([*BASE["benchmark"], "--instance", "{train_id}", "--instance", "{train_id}"], "--instance",
     "{train_id}"),
    ([*BASE["benchmark"][:-2], "--reference", "--seed-from", "{o}/nope"], "--seed-from", "nope"),
    ([*BASE["benchmark"], "--seed-from", "{d}"], "--seed-from", "--reference"),
    ([*BASE["benchmark"][:-2], "--reference", "--seed-from", "{d}"], "--seed-from",
     "holds no servobench-v1.json"),
    (["benchmark", "--out", "{d}", "--dry-run", "--reference", "--seed-from", "{d}/folder"],
     "--seed-from", "no finished"),
    ([*BASE["benchmark"], "--reference"], "--tuners", "--reference"),
    (["benchmark", "--out", "{d}/p.json/sub", "--dry-run", "--tuners", "tpe"], "--out", "p.json"),
    ([*BASE["train"], "--algo-kwargs", '{"batch_size": 0}'], "batch_size", "0"),
    ([*BASE["train"], "--algo-kwargs", '{"learning_rate": "x"}'], "learning_rate", "'x'"),
    ([*BASE["train"], "--algo-kwargs", '{"device": "cuda"}'], "device", "'cuda'"),
    ([*BASE["train"], "--algo-kwargs", '{"gamma": 2}'], "gamma", "2"),
    ([*BASE["train"], "--env-kwargs", '{"plant": "arm"}'], "--env-kwargs", "'arm'"),
    ([*BASE["train"], "--env-kwargs", '{"family": "pmac"}'], "--env-kwargs", "'pmac'"),
    ([*BASE["train"], "--env-kwargs", '{"privileged": "no"}'], "privileged", "'no'"),
    ([*BASE["train"], "--env-kwargs", '{"params": ["kp", "kp"]}'], "params", "'kp'"),
    ([*BASE["train"], "--resume"], "--resume", "config.json"),
    ([*BASE["train"], "--timesteps", "10000000000"], "--timesteps", "10000000000"),
    ([*BASE["train"], "--n-envs", "100000"], "--n-envs", "100000"),
    ([*BASE["evaluate"], "--model", "{d}/fifo"], "--model", "fifo"),
    ([*BASE["evaluate"], "--model", "/dev/zero"], "--model", "/dev/zero"),
    ([*BASE["evaluate"], "--model", "{d}/folder"], "--model", "folder"),
    ([*BASE["evaluate"], "--model", "{d}/run_deep/model.zip"], "--model", "nested"),
    ([*BASE["evaluate"], "--model", "{d}/run_list/model.zip"], "--model", "array"),
    ([*BASE["evaluate"], "--model", "{d}/run_keys/model.zip"], "--model", "algo"),
    ([*BASE["evaluate"], "--model", "{d}/run_kwargs/model.zip"], "--model", "env_kwargs"),
    ([*_drop(BASE["evaluate"], "--episodes"), "--episodes", "1000000000"], "--episodes",
     "1000000000"),
]  # fmt: skip
"""Contradictions, out-of-range values and secrets: (argv, option, value in the message)."""

CASES = [
    *[("file", *c) for c in _file_cases()],
    *[("option", *c) for c in _option_cases()],
    *[("contradiction", *c) for c in CONTRADICTIONS],
]


def _id(case) -> str:
    kind, argv, option, _ = case
    return f"{kind}:{argv[0]}:{option}:{' '.join(argv[1:])[-40:]}"


# ------------------------------------------------------------------------------ fixtures


def _manifest(files: object) -> str:
    return json.dumps({"format": "servogym-file-set", "token": "0" * 12, "files": files})


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    from servogym.chips import families

    d = tmp_path_factory.mktemp("suite")
    text = to_json(PMDParams(model="MC2100", kp=300))
    (d / "p.json").write_text(text)
    parker = families()["parker6k"]
    (d / "p6250.prg").write_text(parker.export(parker.make_params("6250"), "6250"))
    (d / "folder").mkdir()
    (d / "servobench-v1.json").write_text('{"instances": {}}')
    os.mkfifo(d / "fifo")
    (d / "empty.json").write_text("")
    (d / "binary.bin").write_bytes(b"\x00\xff\xfe\x80" * 10)
    (d / "deep.json").write_text(DEEP)
    (d / "deep_obj.json").write_text('{"format": "servogym-params", "x": ' + DEEP + "}")
    (d / "huge.json").write_text(" " * (5 * 1024 * 1024) + text)
    (d / "array.json").write_text("[1, 2]")
    (d / "string.json").write_text('"kp"')
    (d / "cut.json").write_text(text[: len(text) // 2])
    doc = json.loads(text)
    del doc["checksum"]
    body = json.dumps(doc, indent=2)
    (d / "dup.json").write_text(body.replace('"kp": 300', '"kp": 100, "kp": 32000'))
    (d / "nan.json").write_text(body.replace('"kp": 300', '"kp": NaN'))
    for name, manifest in (
        ("mdeep", '{"format": "servogym-file-set", "files": ' + DEEP + "}"),
        ("mlist", "[]"),
        ("mstr", _manifest({"p.json": "abc"})),
        ("mgarbage", "garbage{"),
    ):
        (d / name).mkdir()
        (d / name / "p.json").write_text(text)
        (d / name / "manifest.json").write_text(manifest)
    good = {"env_id": ENV, "algo": "ppo", "env_kwargs": {}, "algo_kwargs": {}}
    for name, cfg in (
        ("run_deep", '{"algo": ' + DEEP + "}"),
        ("run_list", "[]"),
        ("run_keys", json.dumps({"env_id": ENV})),
        ("run_kwargs", json.dumps({**good, "env_kwargs": [1]})),
    ):
        (d / name).mkdir()
        (d / name / "config.json").write_text(cfg)
        (d / name / "model.zip").write_bytes(b"PK\x05\x06" + b"\x00" * 18)
    return d


def _listing(folder: Path) -> dict[str, tuple[int, int]]:
    out = {}
    for root, dirs, names in os.walk(folder):
        for n in names + dirs:
            p = Path(root) / n
            st = os.lstat(p)
            out[str(p.relative_to(folder))] = (st.st_size, st.st_mtime_ns)
    return out


@pytest.fixture(scope="module")
def train_id() -> str:
    from servogym.autotune.bench._suite import get_suite

    return get_suite().ids("train")[0]


@contextlib.contextmanager
def _alarm(seconds: int):
    def _raise(*_):
        raise TimeoutError(f"the command did not finish in {seconds} s (a hang)")

    old = signal.signal(signal.SIGALRM, _raise)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


# ------------------------------------------------------------------------------ tests


def test_the_suite_covers_every_command_class_and_damage():
    kinds = {c[0] for c in CASES}
    commands = {c[1][0] for c in CASES}
    assert kinds == {"file", "option", "contradiction"}
    assert set(BASE) <= commands
    assert len(_file_cases()) == len(FILE_INPUTS) * len(FILE_DAMAGE) - 1
    # every integer and float option of every command with a base line gets its damage
    n_typed = sum(
        _kind(p) in ("int", "float") and not getattr(p, "count", False)
        for c in BASE for p in COMMANDS[c].params if any(o.startswith("--") for o in p.opts)
    )  # fmt: skip
    assert n_typed >= 20
    assert len(CASES) >= 300, len(CASES)


@pytest.mark.parametrize("case", CASES, ids=_id)
def test_refused_in_one_line_with_nothing_written(files, train_id, tmp_path, case):
    _, args, option, value = case
    out = tmp_path / "o"
    argv = [
        a.replace("{d}", str(files)).replace("{o}", str(out)).replace("{train_id}", train_id)
        for a in args
    ]
    value = value.replace("{train_id}", train_id)
    before = _listing(files)
    with _alarm(60):
        result = CliRunner().invoke(app, argv)
    text = result.output
    assert result.exit_code == 2, (argv, result.exit_code, text[-2000:])
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        argv, repr(result.exception))  # fmt: skip
    assert "Traceback" not in text, text
    assert SECRET not in text, text
    errors = [line for line in text.splitlines() if line.lower().startswith("error:")]
    assert len(errors) == 1, (argv, text)
    others = [
        line for line in text.splitlines()
        if line.strip() and line not in errors and not line.startswith(("Usage:", "Try '"))
    ]  # fmt: skip
    assert not others, (argv, text)
    assert option in errors[0] and value in errors[0], (argv, errors[0])
    assert not out.exists() or _listing(out) == {}, (argv, _listing(out))
    assert _listing(files) == before, argv


# ------------------------------------------------------------------------------ env constructors

IDS = sorted(i for i in gym.registry if i.startswith("servogym/"))


def _other(id_: str, kind: str) -> tuple[str, str]:
    from servogym._registration import _ID_PARTS, BUILTIN_PLANTS

    _, family, plant = _ID_PARTS[id_]
    if kind == "plant":
        return "plant", next(p for p in BUILTIN_PLANTS if p != plant)
    return "family", next(f for f in ("pmd", "pmac", "parker6k") if f != family)


@pytest.mark.parametrize("kind", ["plant", "family"])
@pytest.mark.parametrize("env_id", IDS)
def test_env_keywords_that_contradict_the_id_are_refused(env_id, kind):
    key, value = _other(env_id, kind)
    with pytest.raises(ValueError, match=rf"{key}={value!r} contradicts the env id {env_id}"):
        gym.make(env_id, **{key: value})


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"privileged": "no"}, r"privileged must be True or False; got privileged='no'"),
        ({"privileged": 1}, r"privileged must be True or False; got privileged=1"),
        ({"params": ("kp", "kp")}, r"params names 'kp' twice"),
        ({"params": "kp"}, r"params must be a sequence of register names"),
    ],
)
def test_env_keyword_values_are_checked_not_coerced(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(ENV, **kwargs)
