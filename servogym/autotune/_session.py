"""A tuning session: one Optuna study in a storage, shared by every worker that joins it.

The study lives in its storage and nowhere else, the way Optuna's distributed optimization
works: every worker, a thread pool in one process or processes on many machines, asks and
tells on the same study, and the storage numbers the trials. Several ``servogym tune
--storage URL --study-name NAME`` processes therefore share one study:

* **the budget is the study's**: a worker asks only while the trials that count (every
  trial except those failed for a dead worker or over the budget, see
  :func:`counts_toward_budget`) are fewer than the budget, and stops when that many are
  finished; trials still running on other workers are waited for, so a study ends with
  exactly ``budget`` counted trials, none evaluated twice;
* **a killed worker loses nothing**: every running trial carries a heartbeat (Optuna's own
  on an RDB storage, the same interface on a journal file, :class:`JournalFileStorage`);
  a trial whose heartbeat stops for ``grace_period`` seconds is failed by the next worker
  that looks (``optuna.storages.fail_stale_trials``) and queued again with the same
  parameters (``RetryHeartbeatStaleTrialCallback``), and a worker that is interrupted
  (Ctrl-C, an exception) fails and re-queues its own trials at once.

Storages: a file path is an Optuna journal file (the default, ``OUT/study.journal``: one
append per write, no database round trip), anything with ``://`` an Optuna RDB URL
(``sqlite:///...``, ``postgresql://...``), ``None`` memory only.

Determinism. Samplers ask in batches of ``batch_size`` trials, all of a batch before any of
it is told; each trial is evaluated as soon as it is asked (a thread pool; each thread owns
its own :class:`~servogym.sim.Evaluator`) and told when the whole batch is asked. The
sampler that asks trial ``n`` is built from a seed derived from ``(seed, n)``. With one
worker process a trial's parameters are thus a function of the seed, its number and the
trials of earlier batches only: the same seed gives the same study whatever the number of
threads. Several processes on one study interleave their trials, so their study depends on
timing (every trial is still asked by a seeded sampler; no two workers repeat one).
"""

from __future__ import annotations

import bisect
import concurrent.futures as cf
import contextlib
import dataclasses
import json
import logging
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from servogym.autotune._problem import Outcome, TuneProblem

logger = logging.getLogger(__name__)

DEFAULT_BATCH_SIZE = 8
"""Trials asked per batch: enough to keep 8 cores busy, few enough for TPE to learn."""

HEARTBEAT_INTERVAL_S = 5
"""Seconds between two heartbeats of a running trial."""

GRACE_PERIOD_S = 20
"""Seconds without a heartbeat after which a running trial counts as abandoned."""

MAX_RETRY = 3
"""Times an abandoned trial is queued again with the same parameters."""

POLL_S = 0.25
"""Seconds a worker waits before looking again at trials other workers are running."""

CONFIG_KEY = "servogym:config"
HEARTBEAT_KEY = "servogym:heartbeat"

KINDS = ("warm_start", "sample", "candidate", "experiment")
"""What a trial is: the warm-start set, a sampler's proposal, a classical tuner's candidate
(scored on the scenario), or a classical tuner's experiment (a measurement, no cost; stored
as a PRUNED trial)."""


class TuneError(ValueError):
    """A tuning run cannot start or continue as asked (the message says why and what to do)."""


class BudgetExhausted(Exception):
    """A tuner asked for an evaluation beyond its budget."""


ProgressCallback = Callable[[int, int, float | None], None]
"""Called with (evaluations done, budget, best cost so far or None) after every trial."""


def trial_seed(seed: int, number: int) -> int:
    """The sampler seed used to ask trial ``number`` of a study seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, number, 0x5EED]).generate_state(1)[0])


def default_storage_url(out_dir: str | Path) -> str:
    """``DIR/study.journal``, the default storage of a run folder (an Optuna journal file).

    A run folder written by servogym 0.1 before studies were shared holds ``study.db``
    instead; its SQLite URL is returned then, so ``--resume`` continues it. That URL is built
    with SQLAlchemy's URL API, so a folder name with ``?``, ``%``, ``#`` or ``@`` is quoted
    and names that folder.
    """
    from sqlalchemy.engine import URL

    folder = Path(out_dir).resolve()
    if (folder / "study.db").exists() and not (folder / "study.journal").exists():
        db = str(folder / "study.db")
        return URL.create("sqlite", database=db).render_as_string(hide_password=False)
    return str(folder / "study.journal")


def counts_toward_budget(trial: Any) -> bool:
    """Whether a trial uses the budget: every trial except a failed one without an ``error``
    (a worker died or was interrupted: it is queued again; or it was asked over the budget)."""
    if trial.state.name == "FAIL":
        return "error" in trial.user_attrs
    return True


# ---------------------------------------------------------------------------- storages


def _journal_storage_class() -> type:
    from optuna.storages import JournalStorage
    from optuna.storages._heartbeat import BaseHeartbeat

    class _JournalFileStorage(JournalStorage, BaseHeartbeat):
        """An Optuna journal storage with heartbeats (see :func:`open_storage`).

        A heartbeat is a system attribute of the trial; a running trial that has none yet
        beats from its start time, so asking a trial costs no extra write.
        """

        beats_from_start = True

        def __init__(self, backend: Any, heartbeat_interval: int, grace_period: int,
                     callback: Any) -> None:  # fmt: skip
            super().__init__(backend)
            self._heartbeat_interval = heartbeat_interval
            self._grace_period = grace_period
            self._stale_callback = callback

        def record_heartbeat(self, trial_id: int) -> None:
            self.set_trial_system_attr(trial_id, HEARTBEAT_KEY, time.time())

        def _get_stale_trial_ids(self, study_id: int) -> list[int]:
            from optuna.trial import TrialState

            now = time.time()
            stale = []
            for t in self.get_all_trials(study_id, deepcopy=False, states=(TrialState.RUNNING,)):
                beats = [t.system_attrs.get(HEARTBEAT_KEY)]
                if t.datetime_start is not None:
                    beats.append(t.datetime_start.timestamp())
                beat = max((b for b in beats if b is not None), default=None)
                if beat is not None and now - beat > self._grace_period:
                    stale.append(t._trial_id)
            return stale

        def get_heartbeat_interval(self) -> int | None:
            return self._heartbeat_interval

        def get_heartbeat_stale_trial_callback(self) -> Any:
            return self._stale_callback

    return _JournalFileStorage


def _journal_backend(path: Path) -> Any:
    import fcntl
    import os

    from optuna.storages.journal import JournalFileBackend
    from optuna.storages.journal._file import BaseJournalFileLock

    class _FlockLock(BaseJournalFileLock):
        # One flock(2) on a file kept open, instead of Optuna's symlink or O_EXCL lock files
        # (a few file-system operations per write; flock works on local disks and NFS).
        def __init__(self, lock_path: str) -> None:
            self._fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)

        def acquire(self) -> bool:
            fcntl.flock(self._fd, fcntl.LOCK_EX)
            return True

        def release(self) -> None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)

        def __del__(self) -> None:
            with contextlib.suppress(OSError, AttributeError):
                os.close(self._fd)

    class _Backend(JournalFileBackend):
        # Optuna's file backend syncs every write to disk and re-opens the file at every
        # read and write. Here the file stays open: a write is one append under the lock;
        # like SQLite's WAL mode with synchronous=NORMAL, it survives the process being
        # killed (only an OS crash could lose the last lines). A read first checks the
        # file's size, so a study with nothing new costs one fstat(2).
        def __init__(self, file_path: str, lock_obj: Any) -> None:
            super().__init__(file_path, lock_obj)
            self._append_fd = os.open(file_path, os.O_WRONLY | os.O_APPEND)
            self._read_file = open(file_path, "rb")  # noqa: SIM115  (kept open)

        def __del__(self) -> None:
            with contextlib.suppress(OSError, AttributeError):
                os.close(self._append_fd)
                self._read_file.close()

        def append_logs(self, logs: list[dict[str, Any]]) -> None:
            text = "\n".join(json.dumps(log, separators=(",", ":")) for log in logs) + "\n"
            data = text.encode("utf-8")
            self._lock.acquire()
            try:
                while data:  # a regular file takes it in one write; loop for safety
                    data = data[os.write(self._append_fd, data) :]
            finally:
                self._lock.release()

        def read_logs(self, log_number_from: int) -> Any:
            f = self._read_file
            size = os.fstat(f.fileno()).st_size
            offsets = self._log_number_offset
            start = offsets.get(log_number_from)
            if start is not None and start == size:
                return iter(())
            return self._read_from(log_number_from, size)

        def _read_from(self, log_number_from: int, size: int) -> Any:
            # Optuna's JournalFileBackend.read_logs, on the open file.
            f = self._read_file
            offsets = self._log_number_offset
            remaining = size
            start_number = 0
            f.seek(0)
            if log_number_from in offsets:
                f.seek(offsets[log_number_from])
                start_number = log_number_from
                remaining -= offsets[log_number_from]
            last_error: Exception | None = None
            for number, line in enumerate(f, start=start_number):
                remaining -= len(line)
                if remaining < 0:
                    break
                if last_error is not None:
                    raise last_error
                if not line.endswith(b"\n"):
                    last_error = ValueError("Invalid log format.")
                    continue
                if number + 1 not in offsets:
                    offsets[number + 1] = offsets[number] + len(line)
                if number < log_number_from:
                    continue
                try:
                    yield json.loads(line)
                except json.JSONDecodeError as err:
                    last_error = err
                    del offsets[number + 1]
                except RecursionError:  # a damaged line nested too deep to parse
                    last_error = ValueError(f"line {number + 1} is nested too deep")
                    del offsets[number + 1]

    # Not Optuna's ".lock" name: optuna-dashboard opening the file uses a symlink lock there.
    return _Backend(str(path), _FlockLock(str(path) + ".flock"))


def _retry_callback() -> Any:
    """Optuna's retry of a stale trial, queuing a copy without the old trial's constraints,
    heartbeat and sampler state (only its parameters, user attributes and retry history)."""
    import copy

    try:
        from optuna.storages import RetryHeartbeatStaleTrialCallback as Retry
    except ImportError:  # Optuna < 4.9
        from optuna.storages import RetryFailedTrialCallback as Retry
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        retry = Retry(max_retry=MAX_RETRY)

    def callback(study: Any, trial: Any) -> None:
        trial = copy.copy(trial)
        keep = ("failed_trial", "retry_history")
        trial._system_attrs = {k: v for k, v in trial.system_attrs.items() if k in keep}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            retry(study, trial)

    return callback


def open_storage(
    url: str | None,
    *,
    heartbeat_interval: int | None = None,
    grace_period: int | None = None,
) -> Any:
    """The Optuna storage for ``url``, with heartbeats, or a :class:`TuneError` in one line.

    Args:
        url: ``None`` (memory only); a file path (an Optuna journal file, created if
            missing: the default, fastest on one machine, and shared by processes on one
            machine or over NFS); or an RDB URL: ``sqlite:///path/study.db``,
            ``postgresql://user:password@host/db`` (needs ``pip install 'servogym[postgres]'``),
            ``mysql+pymysql://...``.
        heartbeat_interval: Seconds between heartbeats of a running trial (default
            :data:`HEARTBEAT_INTERVAL_S`).
        grace_period: Seconds without a heartbeat after which a running trial is failed and
            queued again (default :data:`GRACE_PERIOD_S`).

    A SQLite file is switched to write-ahead logging with ``synchronous=NORMAL`` and waits
    up to 60 s for a lock, so several processes can share it.
    """
    import optuna

    heartbeat_interval = heartbeat_interval or HEARTBEAT_INTERVAL_S
    grace_period = grace_period or GRACE_PERIOD_S
    if url is None:
        return optuna.storages.InMemoryStorage()
    if not isinstance(url, str):
        return url  # a storage object already
    if "://" not in url:
        path = Path(url).expanduser()
        if not url.strip() or ":" in path.name:
            raise TuneError(
                f"cannot open the study storage {url!r}: it is neither a journal file path "
                "(a file name without ':', e.g. runs/x/study.journal) nor a database URL "
                "(scheme://..., e.g. sqlite:///runs/x/study.db)."
            )
        if not path.parent.is_dir():
            raise TuneError(
                f"cannot open the study storage {url!r}: the folder {str(path.parent)!r} "
                "does not exist."
            )
        if path.is_dir():
            raise TuneError(
                f"cannot open the study storage {url!r}: it is a folder; give a journal file "
                f"path such as {str(path / 'study.journal')!r}."
            )
        _check_journal_file(path, url)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # JournalStorage is experimental in some versions
                return _journal_storage_class()(
                    _journal_backend(path), heartbeat_interval, grace_period, _retry_callback()
                )
        except OSError as exc:
            raise TuneError(
                f"cannot open the study storage {url!r}: {exc.strerror or exc}."
            ) from None
        # Not JSON lines (ValueError), or JSON that is no journal operation: Optuna's replay
        # raises KeyError, TypeError or AssertionError("Should not reach.").
        except (ValueError, KeyError, TypeError, AssertionError) as exc:
            raise TuneError(
                f"cannot open the study storage {url!r}: not an Optuna journal file "
                f"({_one_line(exc).rstrip('.')})."
            ) from None
    return _open_rdb(url, heartbeat_interval, grace_period)


def _check_journal_file(path: Path, url: str) -> None:
    """Refuse an existing file that is not an Optuna journal before anything is appended to
    it: its first line must be a whole JSON object with an ``op_code``."""
    import os
    import stat

    from servogym._input import json_depth_error

    try:  # O_NONBLOCK: a FIFO given as --storage must not wait for a writer
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        return
    except OSError as exc:
        raise TuneError(f"cannot open the study storage {url!r}: {exc.strerror or exc}.") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise TuneError(
                f"cannot open the study storage {url!r}: it is not a regular file (a device, "
                "FIFO or socket); give a journal file path."
            )
        head = os.read(fd, 1 << 20)
    except OSError as exc:
        raise TuneError(f"cannot open the study storage {url!r}: {exc.strerror or exc}.") from None
    finally:
        os.close(fd)
    if not head:
        return  # empty: a new journal
    first = head.split(b"\n", 1)[0] + (b"\n" if b"\n" in head else b"")
    try:
        ok = (
            first.endswith(b"\n")
            and json_depth_error(first) is None
            and "op_code" in json.loads(first)
        )
    except (ValueError, TypeError, RecursionError):
        ok = False
    if not ok:
        raise TuneError(
            f"cannot open the study storage {url!r}: not an Optuna journal file (its first "
            "line is not a journal operation); nothing was written to it."
        )


def _open_rdb(url: str, heartbeat_interval: int, grace_period: int) -> Any:
    shown = _redact(url)
    scheme, _, rest = url.partition("://")
    if scheme in ("postgresql", "postgres"):
        # Whichever driver is installed (SQLAlchemy 2.0 defaults to psycopg2, 2.1 to psycopg).
        import importlib.util

        drivers = [d for d in ("psycopg", "psycopg2") if importlib.util.find_spec(d)]
        if not drivers:
            raise TuneError(
                f"the storage {shown!r} needs a PostgreSQL driver: "
                "pip install 'servogym[postgres]'."
            )
        url = f"postgresql+{drivers[0]}://{rest}"
    kwargs: dict[str, Any] = {}
    if scheme == "sqlite":
        kwargs["connect_args"] = {"timeout": 60}
    for attempt in range(8):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                storage = _rdb_storage_class()(
                    url,
                    engine_kwargs=kwargs,
                    heartbeat_interval=heartbeat_interval,
                    grace_period=grace_period,
                    **{_rdb_callback_kwarg(): _retry_callback()},
                )
            break
        except ImportError as exc:
            hint = (
                "pip install 'servogym[postgres]'"
                if scheme.startswith("postgres")
                else f"install the driver {scheme}:// names (e.g. pip install pymysql for "
                "mysql+pymysql://)"
            )
            raise TuneError(
                f"cannot open the study storage {shown!r}: its database driver is "
                f"missing ({_redact(str(exc))}); {hint}."
            ) from None
        except Exception as exc:  # SQLAlchemy's errors: bad URL, unreachable server, races
            if _is_race(exc) and attempt < 7:
                time.sleep(0.1 * (attempt + 1))  # another process is creating the schema
                continue
            detail = _redact(_one_line(exc))
            raise TuneError(f"cannot open the study storage {shown!r}: {detail}") from None
    if scheme == "sqlite":
        from sqlalchemy import event

        def _pragmas(dbapi_connection: Any, _record: Any) -> None:
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.close()

        event.listen(storage.engine, "connect", _pragmas)
        storage.engine.dispose()  # reconnect with the pragmas
    return storage


def _rdb_storage_class() -> type:
    import datetime

    import optuna
    from optuna.storages._rdb import models
    from optuna.storages._rdb.storage import _create_scoped_session
    from optuna.trial import TrialState
    from sqlalchemy import orm

    class _RDBStorage(optuna.storages.RDBStorage):
        """Optuna's RDB storage, where a running trial without any heartbeat beats from its
        start, as on a journal file: its worker died inside ``study.ask``, after the trial
        was created and before its first heartbeat. Optuna skips such a trial, so every
        worker, and a resume, would wait for it forever."""

        def _get_stale_trial_ids(self, study_id: int) -> list[int]:
            stale = super()._get_stale_trial_ids(study_id)
            grace = self.grace_period or 2 * (self.heartbeat_interval or HEARTBEAT_INTERVAL_S)
            oldest = datetime.datetime.now() - datetime.timedelta(seconds=grace)
            with _create_scoped_session(self.scoped_session) as session:
                running = (
                    session.query(models.TrialModel)
                    .options(orm.selectinload(models.TrialModel.heartbeats))
                    .filter(models.TrialModel.state == TrialState.RUNNING)
                    .filter(models.TrialModel.study_id == study_id)
                    .all()
                )
                stale += [
                    t.trial_id
                    for t in running
                    if not t.heartbeats and t.datetime_start is not None
                    and t.datetime_start < oldest
                ]  # fmt: skip
            return stale

    return _RDBStorage


def _rdb_callback_kwarg() -> str:
    import inspect

    import optuna

    names = inspect.signature(optuna.storages.RDBStorage).parameters
    return (
        "heartbeat_stale_trial_callback"
        if "heartbeat_stale_trial_callback" in names
        else "failed_trial_callback"
    )


def _is_race(exc: Exception) -> bool:
    text = str(exc).lower()
    return any(
        key in text
        for key in ("already exists", "unique constraint", "duplicate key", "database is locked")
    )


def _one_line(exc: BaseException | None) -> str:
    text = str(getattr(exc, "orig", None) or exc).strip()
    line = text.splitlines()[0] if text else type(exc).__name__
    return line.split(" (Background on this error")[0].rstrip(".") + "."


def _redact(url: str) -> str:
    """The URL without its password (SQLAlchemy's rendering, ``user:***@host``)."""
    from servogym._input import mask_url

    return mask_url(url)


def per_trial_sampler(
    make_sampler: Callable[[int], Any], seed: int, timer: Callable[[float], None] | None = None
) -> Any:
    """A sampler that asks trial ``n`` with ``make_sampler(trial_seed(seed, n))``.

    The trial's number is known only once the storage has created it, so the inner sampler
    is built in ``before_trial``; every other call goes to it. ``timer``, if given, is
    called with the CPU seconds of the calling thread spent in each of these calls (the
    sampler's own overhead, building it included).
    """
    import optuna
    from optuna.search_space import IntersectionSearchSpace

    clock = time.thread_time

    def timed(fn: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any) -> Any:
            t0 = clock()
            try:
                return fn(*args)
            finally:
                if timer is not None:
                    timer(clock() - t0)

        return call

    class _PerTrialSeeded(optuna.samplers.BaseSampler):
        def __init__(self) -> None:
            self._inner: Any = None
            self._spaces: dict[Any, Any] = {}

        @timed
        def before_trial(self, study: Any, trial: Any) -> None:
            self._inner = make_sampler(trial_seed(seed, trial.number))
            # The search space of the study, computed incrementally once for all trials
            # (TPE's own is per sampler instance, so it would be recomputed from scratch).
            space = getattr(self._inner, "_search_space", None)
            if isinstance(space, IntersectionSearchSpace):
                key = (type(self._inner), space._include_pruned)
                self._inner._search_space = self._spaces.setdefault(key, space)
            self._inner.before_trial(study, trial)

        @timed
        def infer_relative_search_space(self, study: Any, trial: Any) -> Any:
            return self._inner.infer_relative_search_space(study, trial)

        @timed
        def sample_relative(self, study: Any, trial: Any, search_space: Any) -> Any:
            return self._inner.sample_relative(study, trial, search_space)

        @timed
        def sample_independent(self, study: Any, trial: Any, name: str, dist: Any) -> Any:
            return self._inner.sample_independent(study, trial, name, dist)

        @timed
        def after_trial(self, study: Any, trial: Any, state: Any, values: Any) -> None:
            if self._inner is not None:
                self._inner.after_trial(study, trial, state, values)

        def trial_user_attrs(self) -> dict[str, Any]:
            """User attributes the inner sampler gives the trial it just asked (its
            ``trial_user_attrs``, if any); the session sets them after the ask."""
            return dict(getattr(self._inner, "trial_user_attrs", None) or {})

    return _PerTrialSeeded()


@dataclasses.dataclass
class _Pending:
    trial: Any  # optuna.Trial
    values: dict[str, int]
    kind: str
    futures: list[Any]


class Session:
    """One worker's part of a tuning study: budget, stored study, heartbeats, thread pool.

    Args:
        problem: What is tuned.
        budget: Evaluations (trials) the study holds in the end, warm start and experiments
            included, whatever the number of workers sharing it.
        storage: A journal file path, an Optuna RDB URL (``sqlite:///run/study.db``,
            ``postgresql://...``) or a storage object; ``None`` keeps the study in memory
            only (nothing to resume or share).
        study_name: Name of the study in that storage.
        tuner_name: Stored with the study; every worker and a resume must use the same.
        resume: Continue the study of that name; it must exist.
        load_if_exists: Join the study of that name if it exists, else create it (how
            several workers share one study); without this or ``resume`` the study must
            not exist.
        n_workers: Threads that evaluate in parallel in this process.
        batch_size: Trials a sampler asks before any is told; default
            :data:`DEFAULT_BATCH_SIZE`. Part of the study's identity: a resume uses the
            stored one.
        warm_start: Register values evaluated first (trial 0) when the study is new.
        progress: Called after every finished trial.
        evaluator_factory: Builds one evaluator per thread from the problem's scenario
            (default the problem's own, :meth:`TuneProblem.make_evaluator`).
        heartbeat_interval: Seconds between heartbeats of a running trial (default
            :data:`HEARTBEAT_INTERVAL_S`).
        grace_period: Seconds without a heartbeat after which another worker fails a
            running trial and queues it again (default :data:`GRACE_PERIOD_S`).
        shared: Whether other processes may work on the study at the same time (the
            classical tuners, sequential procedures, cannot).
    """

    def __init__(
        self,
        problem: TuneProblem,
        *,
        budget: int,
        storage: Any,
        study_name: str,
        tuner_name: str,
        resume: bool = False,
        load_if_exists: bool = False,
        n_workers: int = 1,
        batch_size: int | None = None,
        warm_start: Mapping[str, int] | None = None,
        progress: ProgressCallback | None = None,
        evaluator_factory: Callable[[Any], Any] | None = None,
        heartbeat_interval: int | None = None,
        grace_period: int | None = None,
        shared: bool = True,
    ) -> None:
        batch_size_given = batch_size is not None
        batch_size = DEFAULT_BATCH_SIZE if batch_size is None else batch_size
        for name, value, low in (("budget", budget, 1), ("n_workers", n_workers, 1),
                                 ("batch_size", batch_size, 1)):  # fmt: skip
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise TuneError(f"{name} must be an integer >= {low}; got {name}={value!r}.")
        self.problem = problem
        self.budget = budget
        self.tuner_name = tuner_name
        self.n_workers = n_workers
        self.progress = progress
        self.evaluator_factory = evaluator_factory or (lambda _scenario: problem.make_evaluator())
        self.storage_url = storage if isinstance(storage, str) or storage is None else None
        self.study_name = study_name
        self.directions = ["minimize"] * len(problem.objectives)
        self.shared = shared

        config = json.loads(
            json.dumps(
                {
                    "problem": problem.describe(),
                    "tuner": tuner_name,
                    "batch_size": batch_size,
                    "warm_start": dict(warm_start) if warm_start else None,
                }
            )
        )
        self._storage = open_storage(
            storage, heartbeat_interval=heartbeat_interval, grace_period=grace_period
        )
        self.study, created = self._open_study(config, resume, load_if_exists)
        if not created:
            # a joining worker waits for the creator; a resume finds it stored already
            old = self._stored_config(30.0 if load_if_exists else 2.0)
            # A resume or a joining worker repeats the problem and the tuner; batch size and
            # warm start are the stored ones unless given again (then they must agree).
            if warm_start is None:
                config["warm_start"] = old.get("warm_start")
            if not batch_size_given:
                config["batch_size"] = old.get("batch_size", config["batch_size"])
            if old != config:
                raise TuneError(
                    f"the study {study_name!r} in {self._where()} was started with other "
                    "settings; a resume or another worker must repeat them (only the budget "
                    f"and the number of workers may change). Differences: {_diff(old, config)}."
                )
        self.batch_size = int(config["batch_size"])
        self.warm_start = dict(config["warm_start"]) if config["warm_start"] else None

        trials = self.study.get_trials(deepcopy=False)
        counted = [t for t in trials if counts_toward_budget(t)]
        if len(counted) > budget:
            raise TuneError(
                f"the study {study_name!r} already holds {len(counted)} trials, more "
                f"than budget={budget}; pass a budget >= {len(counted)}."
            )
        if not shared and not created and not resume:
            raise TuneError(
                f"the {tuner_name!r} tuner is a sequential procedure and cannot share the "
                f"study {study_name!r} with other workers; continue it in one process with "
                "--resume."
            )

        self._plants = problem.plant_instances()
        self._local = threading.local()
        self._pool: cf.ThreadPoolExecutor | None = None
        self._main_evaluator = self.evaluator_factory(problem.scenario)
        self._main_evaluator.plant.set_params(problem.nominal_plant())  # experiments' plant
        self.fe_limit = problem.following_error_limit(self._main_evaluator)
        self._replay = [t for t in trials if t.state.is_finished() and counts_toward_budget(t)
                        and t.user_attrs.get("kind") != "warm_start"]  # fmt: skip
        self._replay_pos = 0
        self._best: float | None = None
        for t in trials:
            self._note_best(t)
        self._n_finished = sum(t.state.is_finished() for t in counted)
        self._n_counted = len(counted)
        self._running: dict[int, Any] = {}
        self._running_lock = threading.Lock()
        self._heartbeat_stop = threading.Event()
        self._heartbeat_thread: threading.Thread | None = None
        self._beat_at_ask = False
        self._uncounted: list[int] = []
        self._tell_time_s = 0.0
        self._ask_time_s = 0.0
        self._sampler_time_s = 0.0

    # ---------------------------------------------------------------- the study

    def _where(self) -> str:
        return _redact(self.storage_url) if self.storage_url else "memory"

    def _open_study(
        self, config: Mapping[str, Any], resume: bool, load_if_exists: bool
    ) -> tuple[Any, bool]:
        import optuna

        name = self.study_name
        try:
            exists = name in {s.study_name for s in optuna.get_all_study_summaries(self._storage)}
        except Exception as exc:  # SQLAlchemy's errors when the database goes away
            raise TuneError(f"cannot read the study storage {self._where()!r}: "
                            f"{_one_line(exc)}") from None  # fmt: skip
        if exists and not (resume or load_if_exists):
            raise TuneError(
                f"a study named {name!r} already exists in {self._where()}; pass --resume "
                "(resume=True) to continue it, --study-name to join it as another worker, or "
                "choose another --out or --storage."
            )
        if resume and not exists:
            raise TuneError(
                f"nothing to resume: there is no study named {name!r} in {self._where()}. "
                "Run without --resume to start it."
            )
        if not exists:
            try:
                study = optuna.create_study(
                    storage=self._storage, study_name=name, directions=self.directions
                )
            except optuna.exceptions.DuplicatedStudyError:
                if not load_if_exists:
                    raise TuneError(
                        f"a study named {name!r} was just created in {self._where()} by "
                        "another process; pass --study-name to join it."
                    ) from None
            else:
                if config["warm_start"]:
                    values = dict(config["warm_start"])
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        study.enqueue_trial(
                            self.problem.space.to_unit(values),
                            user_attrs={
                                "kind": "warm_start",
                                "registers": values,
                                "note": "warm start",
                            },
                        )
                study.set_user_attr(CONFIG_KEY, config)  # last: joiners wait for it
                return study, True
        return optuna.load_study(study_name=name, storage=self._storage), False

    def _stored_config(self, wait_s: float = 30.0) -> dict[str, Any]:
        deadline = time.monotonic() + wait_s
        while True:
            old = self.study.user_attrs.get(CONFIG_KEY)
            if old is not None:
                return old
            if time.monotonic() > deadline:
                n = len(self.study.get_trials(deepcopy=False))
                where = self._where()
                remedy = "choose another --study-name"
                if self.storage_url and "://" not in self.storage_url and n == 0:
                    remedy = (
                        f"if a servogym tune was stopped while it started (the study holds no "
                        f"trial), remove {where!r} and run the command again without --resume"
                    )
                raise TuneError(
                    f"the study {self.study_name!r} in {where} has no servogym configuration "
                    f"({n} trials), so servogym tune did not finish creating it; {remedy}."
                )
            time.sleep(POLL_S)  # its creator is about to store it

    @property
    def n_done(self) -> int:
        """Finished trials that count toward the budget (this worker's view)."""
        return self._n_finished

    @property
    def remaining(self) -> int:
        """Evaluations left in the budget (trials neither running nor finished)."""
        return self.budget - self._n_counted

    def _refresh(self) -> list[Any]:
        """Fail abandoned trials, re-count the study; return its counted trials."""
        import optuna

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            before = len(self._uncounted)
            optuna.storages.fail_stale_trials(self.study)
        trials = self.study.get_trials(deepcopy=False)
        counted = [t for t in trials if counts_toward_budget(t)]
        self._uncounted = sorted(t.number for t in trials if not counts_toward_budget(t))
        if len(self._uncounted) > before and before:
            logger.info(
                "%d abandoned trial(s) failed and queued again", len(self._uncounted) - before
            )
        self._n_counted = len(counted)
        self._n_finished = sum(t.state.is_finished() for t in counted)
        for t in counted:
            self._note_best(t)
        return counted

    def _note_best(self, t: Any) -> None:
        if t.state.name != "COMPLETE" or t.user_attrs.get("kind") == "experiment":
            return
        self._note(t.values[0], all(v <= 0 for v in t.constraints.values()))

    def _note(self, value: float, feasible: bool) -> None:
        if feasible and (self._best is None or value < self._best):
            self._best = value

    def _report(self) -> None:
        if self.progress is not None:
            self.progress(min(self.n_done, self.budget), self.budget, self._best)

    # ---------------------------------------------------------------- heartbeats

    def _heartbeats_on(self) -> bool:
        from optuna.storages._heartbeat import is_heartbeat_enabled

        return is_heartbeat_enabled(self.study._storage)

    def _beat(self, trial_ids: Sequence[int]) -> None:
        storage = self.study._storage
        for tid in trial_ids:
            with contextlib.suppress(Exception):  # a trial finished meanwhile
                storage.record_heartbeat(tid)

    def _heartbeat_loop(self, interval: float) -> None:
        while not self._heartbeat_stop.wait(interval):
            with self._running_lock:
                ids = list(self._running)
            self._beat(ids)

    def _abandon_running(self) -> None:
        """Fail this worker's running trials and queue them again (an interrupted run)."""
        import optuna

        with self._running_lock:
            ids = list(self._running)
            self._running.clear()
        storage = self.study._storage
        retry = _retry_callback()
        for tid in ids:
            try:
                if storage.set_trial_state_values(tid, state=optuna.trial.TrialState.FAIL):
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        retry(self.study, storage.get_trial(tid))
            except Exception:
                logger.debug("could not re-queue trial %s", tid, exc_info=True)

    # ---------------------------------------------------------------- evaluation

    def __enter__(self) -> Session:
        self._pool = cf.ThreadPoolExecutor(self.n_workers, thread_name_prefix="servogym-eval")
        if self._heartbeats_on():
            self._beat_at_ask = not getattr(self.study._storage, "beats_from_start", False)
            interval = self.study._storage.get_heartbeat_interval()
            self._heartbeat_stop.clear()
            self._heartbeat_thread = threading.Thread(
                target=self._heartbeat_loop, args=(interval,), daemon=True,
                name="servogym-heartbeat",
            )  # fmt: skip
            self._heartbeat_thread.start()
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if exc_type is not None:
            self._abandon_running()
        if self._heartbeat_thread is not None:
            self._heartbeat_stop.set()
            self._heartbeat_thread.join()
            self._heartbeat_thread = None

    def _evaluate_one(self, params: Any, k: int) -> Any:
        state = self._local.__dict__
        if "evaluator" not in state:
            state["evaluator"] = self.evaluator_factory(self.problem.scenario)
            state["plant"] = None
        plant_values = None if state["plant"] == k else self._plants[k]
        evaluation = state["evaluator"].evaluate(params, plant_values)
        state["plant"] = k
        return evaluation

    def _submit(self, params: Any) -> list[Any]:
        if self._pool is None:
            raise RuntimeError("use the Session as a context manager: with Session(...) as s")
        return [self._pool.submit(self._evaluate_one, params, k) for k in range(len(self._plants))]

    def _collect(
        self, items: Sequence[tuple[Mapping[str, int], list[Any]]]
    ) -> Iterator[tuple[int, Outcome]]:
        """Yield ``(index, outcome)`` as the submitted evaluations of each item finish."""
        owner = {fut: (i, k) for i, (_, futs) in enumerate(items) for k, fut in enumerate(futs)}
        results: dict[int, dict[int, Any]] = {}
        k_all = len(self._plants)
        try:
            for fut in cf.as_completed(owner):
                i, k = owner[fut]
                results.setdefault(i, {})[k] = fut.result()
                if len(results[i]) == k_all:
                    evals = [results[i][j] for j in range(k_all)]
                    yield i, self.problem.aggregate(items[i][0], evals)
        finally:
            for fut in owner:
                fut.cancel()

    def evaluate_sets(
        self, sets: Sequence[tuple[Mapping[str, int], Any]]
    ) -> Iterator[tuple[int, Outcome]]:
        """Evaluate ``(values, params)`` pairs on every plant instance, in parallel.

        Yields ``(index, outcome)`` as each set finishes (not necessarily in order).
        """
        items = [(values, self._submit(params)) for values, params in sets]
        yield from self._collect(items)

    def _finish(self, trial: Any, outcome: Outcome, kind: str, extra: Mapping[str, Any]) -> None:
        """Attach an outcome to a running trial and tell it."""
        import optuna

        try:
            self._tell(trial, outcome, kind, extra)
        except optuna.exceptions.UpdateFinishedTrialError:
            # Another worker found no heartbeat for it and failed it; its retry counts.
            logger.warning(
                "trial %d was failed as abandoned by another worker (no heartbeat for %s s); "
                "its queued copy is evaluated instead",
                trial.number,
                self.study._storage.get_heartbeat_interval() if self._heartbeats_on() else "?",
            )
            with self._running_lock:
                self._running.pop(trial._trial_id, None)

    def _tell(self, trial: Any, outcome: Outcome, kind: str, extra: Mapping[str, Any]) -> None:
        t0 = time.thread_time()
        trial.set_user_attr("kind", kind)
        trial.set_user_attr("registers", outcome.values)
        attrs = outcome.to_attrs()
        attrs.pop("values")
        trial.set_user_attr("outcome", attrs)
        for key, value in extra.items():
            trial.set_user_attr(key, value)
        feasible = True
        if self.problem.constraints.enabled:
            for name, value in self.problem.constraint_values(outcome, self.fe_limit).items():
                trial.set_constraint(name, value)
                feasible = feasible and value <= 0
        objectives = self.problem.objective_values(outcome)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*CmaEsSampler will not use them.*")
            self.study.tell(trial, objectives)
        if kind != "experiment":
            self._note(float(objectives[0]), feasible)
        with self._running_lock:
            self._running.pop(trial._trial_id, None)
        self._n_finished += 1
        self._tell_time_s += time.thread_time() - t0

    # ---------------------------------------------------------------- sampler tuners

    def run_sampler(self, make_sampler: Callable[[int], Any]) -> None:
        """Ask, evaluate and tell in batches until the study's budget is used.

        Args:
            make_sampler: Builds the sampler from a seed (called for every trial, with the
                seed of :func:`trial_seed` for the trial's number).
        """
        self.study.sampler = per_trial_sampler(make_sampler, self.problem.seed, self._time_sampler)
        dists = self.problem.space.distributions()
        waited = False
        while True:
            counted = self._refresh()
            self._report()
            if self._n_finished >= self.budget:
                return
            waiting = sum(t.state.name == "WAITING" for t in counted)
            n = min(self.batch_size, self.budget - len(counted) + waiting)
            if n <= 0:
                if not waited:
                    logger.info(
                        "waiting for %d trial(s) running on other workers",
                        len(counted) - self._n_finished,
                    )
                    waited = True
                time.sleep(POLL_S)  # the rest of the budget runs on other workers
                continue
            self._run_batch(n, dists, counted)

    def evaluate_warm_start(self) -> None:
        """Evaluate the queued warm-start set (trial 0 of a new study) on its own."""
        waiting = [t for t in self.study.get_trials(deepcopy=False) if t.state.name == "WAITING"]
        if not waiting or waiting[0].user_attrs.get("kind") != "warm_start":
            return
        import optuna

        if not isinstance(self.study.sampler, optuna.samplers.RandomSampler):
            self.study.sampler = optuna.samplers.RandomSampler(seed=self.problem.seed)
        self._n_counted = sum(map(counts_toward_budget, self.study.get_trials(deepcopy=False)))
        self._run_batch(1, self.problem.space.distributions(), None)

    def _run_batch(self, n: int, dists: Mapping[str, Any], counted: Sequence[Any] | None) -> None:
        """Ask ``n`` trials, evaluating each as soon as it is asked; then tell them."""
        import optuna

        pending: list[_Pending] = []
        t0 = time.thread_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", category=Warning)
            for _ in range(n):
                trial = self.study.ask(dict(dists))
                given = getattr(self.study.sampler, "trial_user_attrs", None)
                for key, value in (given() if given is not None else {}).items():
                    trial.set_user_attr(key, value)  # e.g. the safe tuner's centre
                with self._running_lock:
                    self._running[trial._trial_id] = trial
                if self._beat_at_ask:
                    self._beat([trial._trial_id])
                frozen = getattr(trial, "_cached_frozen_trial", None) or (
                    self.study._storage.get_trial(trial._trial_id)
                )
                frozen_attrs = frozen.system_attrs
                kind = trial.user_attrs.get("kind", "sample")
                queued = kind == "warm_start" or "failed_trial" in frozen_attrs
                if not queued and counted is not None:
                    # Within the budget? Trial numbers are dense and unique in a storage, so
                    # the trials before this one that count are its number minus those that
                    # do not (failed ones never count again: a conservative bound).
                    rank = trial.number - bisect.bisect_left(self._uncounted, trial.number)
                    if rank >= self.budget:
                        trial.set_user_attr("over_budget", True)
                        trial.set_user_attr("note", "asked when other workers had taken the "
                                            "whole budget; not evaluated")  # fmt: skip
                        self.study.tell(trial, state=optuna.trial.TrialState.FAIL)
                        with self._running_lock:
                            self._running.pop(trial._trial_id, None)
                        break
                if kind == "warm_start":
                    values = {k: int(v) for k, v in trial.user_attrs["registers"].items()}
                else:
                    values = self.problem.space.values_from_unit(trial.params)
                try:
                    params = self.problem.space.make_params(values)
                    values = self.problem.space.register_values(params)
                except ValueError as exc:  # a family's cross-register rule
                    trial.set_user_attr("kind", kind)
                    trial.set_user_attr("registers", values)
                    trial.set_user_attr("error", str(exc))
                    self.study.tell(trial, state=optuna.trial.TrialState.FAIL)
                    with self._running_lock:
                        self._running.pop(trial._trial_id, None)
                    self._n_finished += 1
                    continue
                pending.append(_Pending(trial, values, kind, self._submit(params)))
        self._ask_time_s += time.thread_time() - t0
        for i, outcome in self._collect([(p.values, p.futures) for p in pending]):
            p = pending[i]
            self._finish(p.trial, outcome, p.kind, {})
            self._report()

    # ---------------------------------------------------------------- classical tuners

    def _add(self, trial: Any) -> None:
        t0 = time.thread_time()
        self.study.add_trial(trial)
        self._tell_time_s += time.thread_time() - t0
        self._n_counted += 1
        self._n_finished += 1
        self._note_best(trial)
        self._report()

    def _next_replay(self, kind: str, values: Mapping[str, int]) -> Any | None:
        if self._replay_pos >= len(self._replay):
            return None
        t = self._replay[self._replay_pos]
        if t.user_attrs.get("kind") != kind or t.user_attrs.get("registers") != dict(values):
            raise TuneError(
                f"the stored study does not follow this tuner's procedure at trial {t.number} "
                f"(stored {t.user_attrs.get('kind')} {t.user_attrs.get('registers')}, now "
                f"{kind} {dict(values)}); start a new study."
            )
        self._replay_pos += 1
        return t

    def _frozen(self, kind: str, values: Mapping[str, int], outcome: Outcome | None,
                extra: Mapping[str, Any]) -> Any:  # fmt: skip
        import optuna

        unit = self.problem.space.to_unit(values)
        user = {"kind": kind, "registers": dict(values), **extra}
        if outcome is None:
            return optuna.trial.create_trial(
                state=optuna.trial.TrialState.PRUNED,
                params=unit,
                distributions=self.problem.space.distributions(),
                user_attrs=user,
            )
        attrs = outcome.to_attrs()
        attrs.pop("values")
        user["outcome"] = attrs
        constraints = None
        if self.problem.constraints.enabled:
            constraints = self.problem.constraint_values(outcome, self.fe_limit)
        return optuna.trial.create_trial(
            values=self.problem.objective_values(outcome),
            params=unit,
            distributions=self.problem.space.distributions(),
            user_attrs=user,
            constraints=constraints,
        )

    def candidates(self, sets: Sequence[tuple[Mapping[str, int], str]]) -> list[Outcome]:
        """Score register sets on the scenario, one budget unit each (classical tuners).

        Args:
            sets: ``(values, note)`` pairs; values are complete register values.

        Raises:
            BudgetExhausted: when the budget cannot hold them all.
        """
        if len(sets) > self.remaining:
            raise BudgetExhausted(f"{len(sets)} candidates but {self.remaining} evaluations left")
        out: list[Outcome | None] = [None] * len(sets)
        todo = []
        for i, (values, _note) in enumerate(sets):
            old = self._next_replay("candidate", values)
            if old is not None:
                out[i] = Outcome.from_attrs(
                    {**old.user_attrs["outcome"], "values": old.user_attrs["registers"]}
                )
            else:
                todo.append(i)
        # Evaluate the rest in parallel, record in order.
        got = dict(self.evaluate_sets(
            [(sets[i][0], self.problem.space.make_params(sets[i][0])) for i in todo]))  # fmt: skip
        for j, i in enumerate(todo):
            out[i] = got[j]
            self._add(self._frozen("candidate", sets[i][0], got[j], {"note": sets[i][1]}))
        return [o for o in out if o is not None]

    def experiment(
        self, values: Mapping[str, int], note: str, run: Callable[[Any], dict[str, Any]]
    ) -> dict[str, Any]:
        """Run one experiment of a classical tuner on the identification plant.

        The experiment counts one evaluation. Its measurements are stored with the trial, so
        a resumed run replays them instead of simulating again.

        Args:
            values: Complete register values used in the experiment (may include registers
                a tuner does not search, such as the motor limit).
            note: What the experiment is.
            run: Runs it: takes the main thread's :class:`~servogym.sim.Evaluator` (plant at
                the nominal instance) and returns JSON-ready measurements.

        Raises:
            BudgetExhausted: when no evaluation is left.
        """
        if self.remaining < 1:
            raise BudgetExhausted("no evaluation left for an experiment")
        old = self._next_replay("experiment", values)
        if old is not None:
            return dict(old.user_attrs["experiment"])
        result = json.loads(json.dumps(run(self._main_evaluator), default=_json_default))
        self._add(self._frozen("experiment", values, None, {"note": note, "experiment": result}))
        return result

    @property
    def identification_evaluator(self) -> Any:
        """The evaluator experiments run on (main thread only), at the nominal plant."""
        return self._main_evaluator

    # ---------------------------------------------------------------- results

    def trials(self) -> list[Any]:
        """Every trial of the study, in order (other workers' too)."""
        return self.study.get_trials(deepcopy=False)

    def best_trial(self) -> tuple[Any, bool]:
        """The best trial and whether it meets the constraints.

        Single objective: the lowest cost among feasible trials, else among all. Several
        objectives: of the feasible Pareto front, the trial best in the first objective.
        """
        return best_trial(self.trials(), self.problem.multi_objective)

    def overhead(self) -> dict[str, float]:
        """CPU seconds this worker's main thread spent asking (sampler and storage), in the
        sampler alone (part of asking), and telling (storage)."""
        return {
            "ask_s": self._ask_time_s,
            "sampler_s": self._sampler_time_s,
            "tell_s": self._tell_time_s,
        }

    def _time_sampler(self, seconds: float) -> None:
        self._sampler_time_s += seconds


def scored_trials(trials: Sequence[Any]) -> list[Any]:
    """Complete trials with a cost (not experiments)."""
    return [
        t for t in trials
        if t.state.name == "COMPLETE" and t.user_attrs.get("kind") != "experiment"
    ]  # fmt: skip


def is_feasible(trial: Any) -> bool:
    """Whether every constraint value of a trial is <= 0 (a trial without any is)."""
    return all(v <= 0 for v in trial.constraints.values())


def pareto_front(trials: Sequence[Any]) -> list[Any]:
    """Non-dominated trials (all objectives minimized)."""
    front = []
    for t in trials:
        dominated = any(
            all(a <= b for a, b in zip(o.values, t.values, strict=True))
            and any(a < b for a, b in zip(o.values, t.values, strict=True))
            for o in trials
        )
        if not dominated:
            front.append(t)
    return front


def best_trial(trials: Sequence[Any], multi_objective: bool) -> tuple[Any, bool]:
    """See :meth:`Session.best_trial`."""
    scored = scored_trials(trials)
    if not scored:
        raise TuneError("no trial has a cost yet: raise the budget")
    feasible = [t for t in scored if is_feasible(t)]
    pool = feasible or scored
    if multi_objective:
        pool = pareto_front(pool)
    best = min(pool, key=lambda t: (t.values[0], t.number))
    return best, bool(feasible)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def _diff(old: Mapping[str, Any], new: Mapping[str, Any], prefix: str = "") -> str:
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            sub = _diff(a, b, f"{prefix}{key}.")
            if sub:
                out.append(sub)
        elif a != b:
            out.append(f"{prefix}{key}: stored {a!r}, now {b!r}")
    return "; ".join(out)


@contextlib.contextmanager
def quiet_optuna() -> Iterator[None]:
    """Optuna's per-trial INFO logging off for the duration."""
    import optuna

    level = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        yield
    finally:
        optuna.logging.set_verbosity(level)
