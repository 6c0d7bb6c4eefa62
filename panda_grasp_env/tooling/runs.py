"""What every long job (training, recording, benchmarks, evaluation) writes: atomic files and provenance."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import hmac
import json
import os
import platform
import re
import subprocess
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import TypeAdapter, ValidationError

from panda_grasp_env.geometry import is_count, is_number
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_json

Config = TypeVar("Config")
Result = TypeVar("Result")

PACKAGES = ("numpy", "torch", "mujoco", "gymnasium", "stable-baselines3", "sb3-contrib", "panda-grasp-env")


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """A temporary path (``<name>.tmp``) next to ``path`` to write to; renamed onto ``path`` when the block ends
    without error, so readers never see half a file.  Savers that pick a format by suffix must be told it."""
    tmp = path.with_name(path.name + ".tmp")
    yield tmp
    os.replace(tmp, path)


def write_atomically(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def sha256(path: Path) -> str:
    """Hex SHA-256 of a file, read in 1 MiB blocks (replay buffers and datasets can be large)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_json(path: Path, payload: Any) -> None:
    write_atomically(path, json.dumps(payload, indent=2, sort_keys=True))


def versions(packages: tuple[str, ...] = PACKAGES) -> dict[str, str]:
    """Installed versions of ``packages`` (``absent`` if not installed) and Python's."""
    import importlib.metadata as md

    found = {}
    for name in packages:
        try:
            found[name] = md.version(name)
        except md.PackageNotFoundError:
            found[name] = "absent"
    found["python"] = platform.python_version()
    return found


def machine() -> str:
    """CPU model and core count, for model cards and benchmark records."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} logical cores"


@functools.cache
def commit() -> str:
    """Short hash of the checked-out commit of this repository, ``+changes`` if tracked files differ from
    it (the run used code no commit holds), or ``unknown``.  The shipped checkpoint folders do not count:
    a retest rewrites their results, not the code.  Read once per process: a process runs the code it
    imported, so the final test at the end of a two-hour run is labelled with that code, not with commits
    made while it ran."""
    root = Path(__file__).resolve().parents[2]  # the repository (agents/, perception/ and train.py too)
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
        shipped = [":(exclude)agents/checkpoints", ":(exclude)agents/learning/falls/checkpoints"]
        status = ["status", "--porcelain", "--untracked-files=no", "--", ".", *shipped]
        changes = subprocess.run(["git", "-C", str(root), *status], capture_output=True, text=True)
    except OSError:
        return "unknown"
    if not head.stdout.strip():
        return "unknown"
    return head.stdout.strip() + ("+changes" if changes.stdout.strip() else "")


def ray_tasks(
    function: Callable[..., Result], argument_lists: Iterable[tuple[Any, ...]], address: str, num_cpus: float = 1
) -> Iterator[Result]:
    """``function`` called on each of ``argument_lists`` as Ray tasks, results yielded as they finish.

    ``address``: a cluster address, ``"auto"`` (the running cluster) or ``"local"``: a new instance started here
    even when another one runs on this machine (Ray's own default joins the last cluster started here, which
    another process may be shutting down). Ray is shut down when the iteration ends or is abandoned."""
    import ray

    ray.init(address=address, include_dashboard=False, log_to_driver=False)
    try:
        remote = ray.remote(num_cpus=num_cpus)(function)
        pending = [remote.remote(*arguments) for arguments in argument_lists]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])
    finally:
        ray.shutdown()


def interrupt_on_signals() -> None:
    """Let SIGTERM (cluster schedulers, ``kill``) and SIGINT end a long job the way Ctrl-C does: as a
    ``KeyboardInterrupt`` that saves what is finished.  (A shell starts background jobs with SIGINT
    ignored; this restores it.)  A signal that arrives while a garbage-collection callback (jax installs one)
    or a ``__del__`` runs is raised once that code has returned: raised there, Python would print it as ignored
    and the job would go on."""
    import _thread
    import gc
    import signal
    import threading

    def interrupt(signum: int, frame: Any) -> None:
        swallowing = {getattr(getattr(c, "__func__", c), "__code__", None) for c in gc.callbacks}
        while frame is not None:
            if frame.f_code in swallowing or frame.f_code.co_name == "__del__":
                threading.Timer(0.005, _thread.interrupt_main, (signum,)).start()  # this handler again, soon
                return
            frame = frame.f_back
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, interrupt)
    signal.signal(signal.SIGINT, interrupt)


#: Where ``sign_run_files`` records its signatures, inside the run folder.
SIGNATURES = "signatures.json"


#: The signing key's length in bytes.
RUN_KEY_BYTES = 32


def run_key_path() -> Path:
    """Where ``run_key`` keeps this user's key: ``$XDG_STATE_HOME/panda_grasp_env/run_key`` (``~/.local/state/...``)."""
    state = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state")
    return state / "panda_grasp_env" / "run_key"


def run_key() -> bytes:
    """This user's secret for signing run files: ``RUN_KEY_BYTES`` random bytes at ``run_key_path()``, made on
    first use, readable by the user alone.  A key file that is a symlink, belongs to another user, is open to
    group or others, or is not ``RUN_KEY_BYTES`` long could be known to someone else (and signatures forged
    with it): ``ValueError`` says what is wrong and how to mend it."""
    import stat

    path = run_key_path()
    if not path.exists() and not path.is_symlink():
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        try:
            descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
            with os.fdopen(descriptor, "wb") as key:
                key.write(os.urandom(RUN_KEY_BYTES))
        except FileExistsError:  # another job made it first
            pass
    mend = f"delete it (rm {path}) and the next job makes a new one; runs signed with it then resume only with --trust"
    try:  # O_NOFOLLOW: a symlink is refused by the open itself, not by a check another process could race
        descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError as error:
        why = "is a symlink" if path.is_symlink() else f"cannot be read ({error.strerror})"
        raise ValueError(f"run-signing key {path} {why}: {mend}") from None
    facts = os.fstat(descriptor)
    if not stat.S_ISREG(facts.st_mode):
        os.close(descriptor)
        raise ValueError(f"run-signing key {path} is not a regular file: {mend}")
    with os.fdopen(descriptor, "rb") as handle:
        if facts.st_uid != os.getuid():
            raise ValueError(
                f"run-signing key {path} belongs to user id {facts.st_uid}, not to you ({os.getuid()}): {mend}"
            )
        if facts.st_mode & 0o077:
            raise ValueError(
                f"run-signing key {path} has mode {stat.S_IMODE(facts.st_mode):04o}, not 0600: group or "
                f"others may have read it, so {mend}"
            )
        key = handle.read(RUN_KEY_BYTES + 1)
    if len(key) != RUN_KEY_BYTES:
        size = f"{len(key)} bytes" if len(key) <= RUN_KEY_BYTES else f"more than {RUN_KEY_BYTES} bytes"
        raise ValueError(f"run-signing key {path} holds {size}, not {RUN_KEY_BYTES}: {mend}")
    return key


def _signature(run_dir: Path, name: str) -> str:
    message = f"{run_dir.resolve()}\n{name}\n{sha256(run_dir / name)}".encode()
    return hmac.new(run_key(), message, hashlib.sha256).hexdigest()


def sign_run_files(run_dir: Path, names: list[str]) -> None:
    """Record, in the run's signatures.json, that this user's job wrote ``names`` in this folder as they are now.

    Resume files that only a pickle can hold (SB3's model zip, its replay buffer) run code when loaded;
    ``check_run_files`` loads them only if the signature matches, i.e. this user wrote them in this folder."""
    path = run_dir / SIGNATURES
    signatures = read_json(path, 1 << 20) if path.is_file() else {}
    signatures.update({name: _signature(run_dir, name) for name in names})
    write_json(path, signatures)


def is_signed(run_dir: Path, name: str) -> bool:
    """Whether ``sign_run_files`` signed file ``name`` of ``run_dir`` as it is now, in this folder."""
    path = run_dir / SIGNATURES
    signatures = read_json(path, 1 << 20) if path.is_file() else {}
    signed = signatures.get(name) if isinstance(signatures, dict) else None
    if not isinstance(signed, str) or not (run_dir / name).is_file():
        return False
    return hmac.compare_digest(signed, _signature(run_dir, name))


def check_run_files(run_dir: Path, names: list[str]) -> None:
    """``ValueError`` naming the first of ``names`` that ``sign_run_files`` did not sign as it is now, here."""
    for name in names:
        if not is_signed(run_dir, name):
            raise ValueError(
                f"{run_dir / name} was not written by this user's job in this folder, or has changed since: it is "
                "a pickle, and loading it would run any code it holds (pass --trust to load it anyway)"
            )


def config_value_error(key: str, value: Any, expected: str) -> ValueError:
    """The error of a config key's bad value: ``config <key>=<value>: expected <what it takes>``."""
    return ValueError(f"config {key}={value!r}: expected {expected}")


#: A number in exponent form (``3e-4``), which YAML 1.1 reads as a string.
EXPONENT_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def apply_key_values(target: dict[str, Any], pairs: Sequence[str], what: str) -> dict[str, Any]:
    """``target`` with command-line ``KEY=VALUE`` strings applied: each value read as YAML (a number in exponent
    form as a float, which YAML 1.1 reads as a string), a dotted key reaching into mappings
    (``algo_kwargs.learning_rate=3e-4``).  ``ValueError`` naming ``what`` (``override``, ``--task-options``) and
    the pair that is not KEY=VALUE, whose value is not YAML, or whose dotted key meets a value that is not a
    mapping."""
    for pair in pairs:
        key, equals, text = pair.partition("=")
        if not equals or not key.strip():
            raise ValueError(f"{what} {pair!r} is not KEY=VALUE (dotted keys reach into mappings)")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as error:
            problem = getattr(error, "problem", None) or type(error).__name__
            raise ValueError(f"{what} {pair!r}: the value is not YAML ({problem})") from None
        if isinstance(value, str) and EXPONENT_NUMBER.fullmatch(value.strip()):
            value = float(value)
        *parents, leaf = key.strip().split(".")
        mapping = target
        for parent in parents:
            mapping = mapping.setdefault(parent, {})
            if not isinstance(mapping, dict):
                raise ValueError(f"{what} {pair!r}: {parent!r} is not a mapping")
        mapping[leaf] = value
    return target


def checked_config(cls: type[Config], raw: Any, source: str) -> Config:
    """The pydantic dataclass ``cls`` from the mapping ``raw`` (read from ``source``), checked.  ``ValueError``
    listing unknown or missing keys beside the valid ones, or naming the first bad key, its value and what it
    takes (the field's ``description``, else what its check said); a check across keys raises its own."""
    try:
        return TypeAdapter(cls).validate_python(raw)
    except ValidationError as error:
        problems = error.errors(include_url=False)
    fields = cls.__pydantic_fields__  # type: ignore[attr-defined]
    valid = list(fields)
    keys = [p for p in problems if len(p["loc"]) == 1]  # a tuple too short also reports items "missing"
    unknown = [p["loc"][0] for p in keys if p["type"] in ("unexpected_keyword_argument", "invalid_key")]
    if unknown:
        raise ValueError(f"unknown key(s) {unknown} in {source}; valid keys: {valid}")
    missing = [p["loc"][0] for p in keys if p["type"] == "missing"]
    if missing:
        raise ValueError(f"{source} lacks required key(s) {missing}; valid keys: {valid}")
    first = problems[0]
    said = str(first.get("ctx", {}).get("error", first["msg"]))
    if not first["loc"]:
        raise ValueError(said)
    key = first["loc"][0]
    raise config_value_error(key, raw[key], fields[key].description or said)


def new_run_folder(runs_dir: Path, config: Any, **facts: Any) -> Path:
    """A fresh folder ``runs_dir/<name>-seed<seed>[-N]`` for a run of the config dataclass ``config``, holding
    config.yaml and meta.json (seed, versions, commit, machine, start time and ``facts``)."""
    runs_dir.mkdir(parents=True, exist_ok=True)
    run_dir = runs_dir / f"{config.name}-seed{config.seed}"
    suffix = 1
    while run_dir.exists():
        suffix += 1
        run_dir = runs_dir / f"{config.name}-seed{config.seed}-{suffix}"
    run_dir.mkdir()
    write_atomically(run_dir / "config.yaml", yaml.safe_dump(dataclasses.asdict(config), sort_keys=False))
    meta = {
        "seed": config.seed,
        "versions": versions(),
        "commit": commit(),
        "machine": f"{machine()}, no GPU used",
        "started": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        **facts,
    }
    write_json(run_dir / "meta.json", meta)
    return run_dir


def read_progress(path: Path) -> dict[str, Any]:
    """A run's totals (progress.json, or a shipped checkpoint's final.json): steps and wall seconds, read with
    the bounded reader; ``ValueError`` naming the file unless both are numbers >= 0 (steps a whole number)."""
    totals = read_json(path, MAX_DOCUMENT_BYTES)
    steps, wall = (totals.get(k) for k in ("steps", "wall_seconds")) if isinstance(totals, dict) else (None, None)
    if not (is_count(steps) and steps >= 0 and is_number(wall) and wall >= 0):
        raise ValueError(f"{path} must hold steps (a whole number) and wall_seconds (a number >= 0)")
    return {**totals, "steps": int(steps), "wall_seconds": float(wall)}


def record_resume(run_dir: Path, overrides: list[str]) -> None:
    """Append a resumed session to meta.json's ``resumed`` list: when, at which commit, after how many steps
    (progress.json, where the run keeps one) and with which ``key=value`` overrides -- config.yaml holds only
    the latest values, so this is how a card tells a two-stage recipe from a one-stage one."""
    meta = read_json(run_dir / "meta.json", MAX_DOCUMENT_BYTES)
    progress = run_dir / "progress.json"
    session = {"at": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "commit": commit(), "overrides": list(overrides)}
    if progress.is_file():
        session["after_steps"] = read_progress(progress)["steps"]
    meta.setdefault("resumed", []).append(session)
    write_json(run_dir / "meta.json", meta)


def forget_failed_resume(run_dir: Path) -> None:
    """Drop the last ``record_resume`` entry if the run made no progress since it (the session failed to start)."""
    meta = read_json(run_dir / "meta.json", MAX_DOCUMENT_BYTES)
    sessions, progress = meta.get("resumed", []), run_dir / "progress.json"
    steps = read_progress(progress)["steps"] if progress.is_file() else None
    if sessions and sessions[-1].get("after_steps") == steps:
        sessions.pop()
        write_json(run_dir / "meta.json", meta)


def resume_summary(meta: dict[str, Any]) -> str | None:
    """One line for a card: each resumed session's start and overrides (``record_resume``), or None."""
    sessions = [
        ("" if "after_steps" not in r else f"at step {r['after_steps']} ")
        + f"with {' '.join(f'`{o}`' for o in r['overrides']) or 'no changes'}"
        for r in meta.get("resumed", [])
    ]
    return "resumed " + "; ".join(sessions) if sessions else None


def check_resume_changes(
    saved: Any, resumed: Any, changeable: tuple[str, ...], also_fixed: list[str] | None = None
) -> None:
    """``ValueError`` if the config dataclass of a resumed run (``resumed``) differs from the one it was saved
    with in a key outside ``changeable`` (those built its model, data or seeds), naming them and what may change."""
    fixed = [
        f.name
        for f in dataclasses.fields(saved)
        if f.name not in changeable and getattr(saved, f.name) != getattr(resumed, f.name)
    ] + list(also_fixed or [])
    if fixed:
        raise ValueError(
            f"a resumed run cannot change {fixed}: they built its model, data or seeds; it may change {list(changeable)}"
        )
