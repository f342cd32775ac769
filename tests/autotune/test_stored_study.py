"""What users of the stored study see: trials_dataframe, optuna-dashboard, plain Optuna."""

from __future__ import annotations

import json

import optuna

from servogym.autotune import run_study

from .helpers import short_problem


def test_trials_dataframe_and_the_dashboard_show_register_values(tmp_path):
    from optuna_dashboard._serializer import serialize_frozen_trial
    from optuna_dashboard._storage_url import guess_storage_from_url

    path = str(tmp_path / "study.journal")
    result = run_study(short_problem(seed=4), "tpe", 6, storage=path, study_name="s")
    # optuna-dashboard PATH opens the file the way it opens any Optuna journal file
    study = optuna.load_study(study_name="s", storage=guess_storage_from_url(path))
    trials = study.get_trials()
    assert [t.number for t in trials] == [t.number for t in result.trials]
    frame = study.trials_dataframe()
    assert len(frame) == 6 and "user_attrs_registers" in frame.columns
    assert frame["user_attrs_registers"][0] == result.trials[0].user_attrs["registers"]
    system = study._storage.get_study_system_attrs(study._study_id)
    shown = serialize_frozen_trial(study._study_id, trials[0], system)
    attrs = {a["key"]: a["value"] for a in shown["user_attrs"]}
    assert json.loads(attrs["registers"])["kp"] == trials[0].user_attrs["registers"]["kp"]


def test_a_run_folder_of_the_sqlite_era_resumes_from_its_study_db(tmp_path):
    from servogym.autotune import default_storage_url

    assert default_storage_url(tmp_path) == str(tmp_path.resolve() / "study.journal")
    url = f"sqlite:///{tmp_path.resolve() / 'study.db'}"
    run_study(short_problem(seed=4), "random", 3, storage=url, study_name="s")
    assert default_storage_url(tmp_path) == url
    more = run_study(short_problem(seed=4), "random", 5, storage=default_storage_url(tmp_path),
                     study_name="s", resume=True)  # fmt: skip
    assert len(more.trials) == 5


def test_the_package_ships_its_type_marker():
    import importlib.resources

    assert importlib.resources.files("servogym").joinpath("py.typed").is_file()
