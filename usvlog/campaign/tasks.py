"""One run of a campaign: its sources, settings, key, and the task that takes it through the stages.

A run is one source (a field log of any importable format, or a canonical MCAP log) with
the settings it goes through. Its key is the sha256 of the source's content, the settings,
the vessel file's content and the usvlog version, so a re-run of the campaign finds the
run's finished outputs under ``DIR/runs/<run_id>/`` and does not do the work again.

The stages are the public API's functions, handed in as :class:`Stages` by
:func:`usvlog.campaign` (this package sits below the API layer and does not import it).
:func:`run_one` is the task a Dask worker runs: it never raises for a bad run; a stage
that fails ends the run with a row naming the stage and the reason.
"""

from __future__ import annotations

import fnmatch
import glob
import hashlib
import json
import re
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .._version import __version__
from ..errors import ConfigError, InputError
from . import columns as C

STAGES = ("import", "estimate", "identify", "replay")
DEFAULT_STAGES = ("import", "estimate", "identify")   # replay: asked for, or a scenario given
DEFAULT_SCENARIO = "paper-circle"
ROW_FILE = "row.json"
LOG_FILE, ESTIMATE_FILE, VESSEL_FILE = "log.mcap", "estimate.mcap", "vessel.toml"
MAP_FILE = "map.mcap"
"""The run as the campaign map draws it (:func:`map_log`), written by its task: the report reads
these few kB per run instead of every run's estimate (0.45 s each, in one process)."""
MAP_HZ = {"/gnss/fix": 1.0, "/estimate/state": 1.0}   # samples per second of each run on the campaign map
MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class Stages:
    """The stage functions a run goes through (the public API's, given by ``usvlog.campaign``).

    Attributes
    ----------
    load, import_log, save, estimate, identify, replay : callable
        ``usvlog.load``, ``usvlog.import_log``, ``usvlog.save``, ``usvlog.estimate``,
        ``usvlog.identify``, ``usvlog.replay`` (or functions with their signatures).
    """

    load: Callable
    import_log: Callable
    save: Callable
    estimate: Callable
    identify: Callable
    replay: Callable


@dataclass(frozen=True, kw_only=True)
class RunSettings:
    """What every run of a campaign goes through (part of each run's key).

    Attributes
    ----------
    stages : tuple of str
        Stages to run, in pipeline order, from :data:`STAGES` (default
        :data:`DEFAULT_STAGES`: a closed-loop replay means little on an open-loop run, so
        ``replay`` runs only when listed or when ``scenario`` is given).
    estimate_model : str
        ``kinematic`` or ``dynamic`` (``usvlog estimate --model``).
    method : str
        Identification method (``usvlog identify --method``).
    holdout : float
        Last fraction of each run held out for the validation fit % (0 to 0.9).
    fix : dict of str to float
        Known parameters (SI units), e.g. ``{"m": 33.0}``.
    current : bool
        Fit a constant water current per run.
    scenario : str or None
        Closed-loop scenario of the replay stage (a shipped name or a TOML file); giving one
        adds ``replay`` to the stages. None: :data:`DEFAULT_SCENARIO` when ``replay`` is
        listed, else no replay.
    """

    stages: tuple[str, ...] = DEFAULT_STAGES
    estimate_model: str = "kinematic"
    method: str = "output-error"
    holdout: float = 0.25
    fix: dict = field(default_factory=dict)
    current: bool = True
    scenario: str | None = None

    def __post_init__(self):
        bad = [s for s in self.stages if s not in STAGES]
        if bad or not self.stages:
            raise ConfigError(f"--stages {','.join(self.stages)}: unknown stage {bad[0] if bad else '(none)'} "
                              f"(stages: {','.join(STAGES)})")
        asked = set(self.stages) | ({"replay"} if self.scenario is not None else set())
        object.__setattr__(self, "stages", tuple(s for s in STAGES if s in asked))
        if "replay" in self.stages and self.scenario is None:
            object.__setattr__(self, "scenario", DEFAULT_SCENARIO)
        if "import" not in self.stages:
            raise ConfigError("--stages must include import (every run is read through it)")
        if not 0.0 <= self.holdout <= 0.9:
            raise ConfigError(f"holdout {self.holdout} must be in [0, 0.9]")

    def to_dict(self) -> dict:
        """JSON-ready settings (the key's part)."""
        d = asdict(self)
        d["stages"] = list(self.stages)
        d["fix"] = {k: float(v) for k, v in sorted(self.fix.items())}
        return d


@dataclass(frozen=True, kw_only=True)
class RunSpec:
    """One run to do: the source, its vessel, its key and where its outputs go.

    Attributes
    ----------
    source : str
        The source path (file or ROS 2 bag directory).
    sha256 : str
        sha256 of its content (hex).
    vessel : str
        Vessel name (from the vessel map or file; empty: the log's own vessel).
    vessel_file : str or None
        Vessel TOML the stages use (None: the log's own vessel).
    key : str
        sha256 (hex) of content, settings, vessel file and usvlog version.
    run_id : str
        Directory name under ``DIR/runs/``: the source's stem and the key's first 12 digits.
    out_dir : str
        ``DIR/runs/<run_id>``.
    """

    source: str
    sha256: str
    vessel: str
    vessel_file: str | None
    key: str
    run_id: str
    out_dir: str


# -----------------------------------------------------------------------------
# sources, vessels, keys
# -----------------------------------------------------------------------------

def expand_sources(sources) -> list[Path]:
    """Files, ROS 2 bag directories, directories of logs and globs -> the run sources, sorted.

    A directory that is a ROS 2 bag (``metadata.yaml`` or ``*.db3`` inside) is one source;
    any other directory gives the files in it (not hidden ones, not recursively). A glob is
    expanded (``**`` recursive).

    Raises
    ------
    usvlog.errors.InputError
        A path that does not exist, a glob that matches nothing, or no sources at all.
    """
    out: list[Path] = []
    for s in sources:
        s = str(s)
        if any(ch in s for ch in "*?["):
            hits = sorted(glob.glob(s, recursive=True))
            if not hits:
                raise InputError(f"{s}: the pattern matches no file")
            paths = [Path(h) for h in hits]
        else:
            p = Path(s)
            if not p.exists():
                raise InputError(f"{p}: no such file or directory")
            paths = [p]
        for p in paths:
            if p.is_dir() and not _is_bag(p):
                out.extend(sorted(x for x in p.iterdir() if not x.name.startswith(".") and (x.is_file() or _is_bag(x))))
            else:
                out.append(p)
    seen, uniq = set(), []
    for p in out:
        r = p.resolve()
        if r not in seen:
            seen.add(r)
            uniq.append(p)
    if not uniq:
        raise InputError("no sources: the directories given hold no files")
    return uniq


def _is_bag(p: Path) -> bool:
    return p.is_dir() and ((p / "metadata.yaml").exists() or any(p.glob("*.db3")))


def content_sha256(path) -> str:
    """sha256 (hex) of a file's content, or of a bag directory's files in name order."""
    from ..io.importers import file_identity  # heavy: the importers package (numpy, pandas)

    return file_identity(path)["sha256"]


HASH_CACHE = "hashes.json"
"""The campaign directory's record of each source's sha256 with the size and modification time
(ns) of its files when it was read: a campaign run again hashes only what changed."""


def _stat_signature(path: Path) -> list:
    files = sorted(x for x in path.rglob("*") if x.is_file()) if path.is_dir() else [path]
    return [[str(f.relative_to(path)) if path.is_dir() else "", f.stat().st_size, f.stat().st_mtime_ns]
            for f in files]


def source_hashes(sources, out_dir) -> list[str]:
    """sha256 (hex) of each source's content, as :func:`content_sha256` gives it.

    A source whose files have the size and modification time recorded in
    ``out_dir/hashes.json`` by an earlier campaign is not read again; the others are read
    one after the other (8 threads were tried: the 40 sources of ``bench_campaign.py``, 327 MB,
    hash in 0.2-1.0 s either way, under 2 % of the campaign, so no thread pool; docs/performance.md).
    The record is rewritten (atomically) with every source.

    Parameters
    ----------
    sources : sequence of pathlib.Path
        Source files or bag directories.
    out_dir : pathlib.Path
        The campaign directory (existing).

    Returns
    -------
    list of str
        The sha256 of each source, in order.
    """
    from ..io.atomic import write_text_atomic  # heavy: the io package (numpy)

    cache_file = Path(out_dir) / HASH_CACHE
    try:
        cache = json.loads(cache_file.read_text())
    except (OSError, ValueError):
        cache = {}
    keys = [str(Path(src).resolve()) for src in sources]
    sigs = [_stat_signature(Path(src)) for src in sources]
    shas: list[str | None] = [cache[k]["sha256"] if k in cache and cache[k].get("files") == sig else None
                              for k, sig in zip(keys, sigs)]
    todo = [i for i, h in enumerate(shas) if h is None]
    for i in todo:
        shas[i] = content_sha256(sources[i])
    cache.update({k: {"files": sig, "sha256": h} for k, sig, h in zip(keys, sigs, shas)})
    if todo:
        write_text_atomic(cache_file, json.dumps(cache, indent=0), force=True)
    return [str(h) for h in shas]


def read_vessel_map(path) -> list[tuple[str, str, tuple[str, ...]]]:
    """A vessel map TOML -> [(vessel name, vessel TOML path, source patterns)], in file order.

    The file has one table per vessel::

        [vessel.alpha]
        file = "alpha.toml"                 # relative to the map file
        match = ["alpha_*", "*/alpha/*"]    # shell patterns on the source's name or path

    Raises
    ------
    usvlog.errors.ConfigError
        A vessel without ``file`` or ``match``, or a vessel file that does not exist.
    """
    from ..io.config import read_toml  # heavy: the config reader (tomllib, numpy via the vessel model)

    base = Path(path).parent
    doc = read_toml(path)
    table = doc.get("vessel")
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"{path}: no [vessel.NAME] tables (each with file = ... and match = [...])")
    out = []
    for name, spec in table.items():
        if not isinstance(spec, dict) or "file" not in spec or "match" not in spec:
            raise ConfigError(f"{path}: [vessel.{name}] needs file = \"V.toml\" and match = [\"pattern\", ...]")
        f = (base / str(spec["file"])).resolve()
        if not f.exists():
            raise ConfigError(f"{path}: [vessel.{name}] file {f} does not exist")
        pats = spec["match"] if isinstance(spec["match"], list) else [spec["match"]]
        out.append((str(name), str(f), tuple(str(x) for x in pats)))
    return out


def vessel_for(source: Path, vessel_map) -> tuple[str, str | None]:
    """(vessel name, vessel file) of a source from a vessel map: the first vessel whose
    pattern matches the source's name or path; ("", None) when none does."""
    for name, f, pats in vessel_map:
        if any(fnmatch.fnmatch(source.name, p) or fnmatch.fnmatch(str(source), p) for p in pats):
            return name, f
    return "", None


def _file_sha(path: str | None) -> str:
    if path is None:
        return ""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run_key(sha: str, settings: RunSettings, vessel_file: str | None) -> str:
    """The key of a run: sha256 of content, settings, vessel file content and usvlog version."""
    doc = {"content": sha, "settings": settings.to_dict(), "vessel": _file_sha(vessel_file), "usvlog": __version__}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def make_spec(source: Path, sha: str, settings: RunSettings, out_root: Path, vessel: str,
              vessel_file: str | None) -> RunSpec:
    """The :class:`RunSpec` of one source (its key and output directory)."""
    key = run_key(sha, settings, vessel_file)
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", source.name.split(".")[0] or "run")[:40]
    run_id = f"{stem}-{key[:12]}"
    return RunSpec(source=str(source), sha256=sha, vessel=vessel, vessel_file=vessel_file, key=key, run_id=run_id,
                   out_dir=str(out_root / "runs" / run_id))


def finished_row(spec: RunSpec) -> dict | None:
    """The row of a run finished earlier (its ``row.json``), or None."""
    p = Path(spec.out_dir) / ROW_FILE
    if not p.is_file():
        return None
    try:
        row = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    return row if row.get("key") == spec.key else None


# -----------------------------------------------------------------------------
# the task
# -----------------------------------------------------------------------------

def _is_canonical(path: Path) -> bool:
    """A usvlog canonical MCAP file (the import stage then only reads it)."""
    if path.is_dir():
        return False
    with open(path, "rb") as fh:
        head = fh.read(256)
    return head.startswith(MCAP_MAGIC) and b"usvlog" in head


def run_one(spec: RunSpec, settings: RunSettings, stages: Stages) -> dict:
    """Take one run through the stages; write its outputs; return its row (never raises for a bad run).

    The outputs (``log.mcap``, ``estimate.mcap``, ``vessel.toml`` and ``row.json`` last) are
    written into a temporary directory that takes the place of ``spec.out_dir`` only when
    the run is finished, failed stage or not: an interrupted run leaves no directory, a
    finished one a complete one.

    Parameters
    ----------
    spec : RunSpec
        The run.
    settings : RunSettings
        The stages and their options.
    stages : Stages
        The stage functions.

    Returns
    -------
    dict
        The run's row: every column of :data:`usvlog.campaign.columns.SCHEMA` plus ``key``.
    """
    from ..io.atomic import atomic_dir  # heavy: the io package (numpy)

    t0 = time.perf_counter()
    row = C.empty_row()
    row.update(run_id=spec.run_id, source=spec.source, sha256=spec.sha256, vessel=spec.vessel or None, status=C.OK)
    out = Path(spec.out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_dir(out, force=True) as tmp:
        _stages(spec, settings, stages, tmp, row)
        row["seconds"] = time.perf_counter() - t0
        row["key"] = spec.key
        (tmp / ROW_FILE).write_text(json.dumps(row, indent=1, default=str))
    return row


def _stages(spec: RunSpec, settings: RunSettings, stages: Stages, tmp: Path, row: dict) -> None:
    src = Path(spec.source)
    ves = spec.vessel_file
    stage = "import"
    try:
        if _is_canonical(src):
            log = stages.load(src)
            row.update(C.import_columns(None))
        else:
            res = stages.import_log(src, vessel=ves)
            log = res.log
            row.update(C.import_columns(res))
        stages.save(log, tmp / LOG_FILE)
        row.update(C.log_columns(log))
        row.update(C.check_columns(log))
        if not row["vessel"] and log.vessel is not None:
            row["vessel"] = log.vessel.name
        map_of = log
        if "estimate" in settings.stages:
            stage = "estimate"
            est = stages.estimate(log, tmp / ESTIMATE_FILE, model=settings.estimate_model, vessel=ves)
            row.update(C.estimate_columns(est))
            row.update(C.manoeuvre_columns(est.state, log))
            map_of = est.to_log(log)
        stages.save(map_log(map_of), tmp / MAP_FILE)
        if "identify" in settings.stages:
            stage = "identify"
            idf = stages.identify(log, tmp / VESSEL_FILE, vessel=ves, method=settings.method,
                                  holdout=settings.holdout, fix=dict(settings.fix), current=settings.current)
            row.update(C.identify_columns(idf))
            if row["verdict"] == C.UNUSABLE:
                row["reason"] = f"identify: unusable: {row['verdict_reasons']}"
        if "replay" in settings.stages:
            stage = "replay"
            rlog = stages.load(tmp / ESTIMATE_FILE) if "estimate" in settings.stages else log
            rep = stages.replay(rlog, settings.scenario, vessel=ves, whatif=True)
            row.update(C.replay_columns(rep))
    except Exception as err:  # a bad run is a row with its reason, never the end of the campaign
        row.update(C.failure_columns(stage, err))


def map_log(log):
    """The run as the campaign map draws it: the :data:`MAP_HZ` channels thinned to their rate
    (a season of runs on one map, or the recording grows huge), the metadata kept.

    Parameters
    ----------
    log : usvlog.FieldLog
        A run, with or without its estimate.

    Returns
    -------
    usvlog.FieldLog
        A new log holding only the thinned map channels (frames are row selections of ``log``'s).
    """
    from ..log.fieldlog import FieldLog  # heavy: pandas
    from ..view.data import thin_indices  # heavy: the views' data helpers (numpy)

    out = FieldLog(meta=dict(log.meta), source=log.source)
    for topic, hz in MAP_HZ.items():
        fr = log.get(topic)
        if fr is not None and len(fr):
            out.set(topic, fr.iloc[thin_indices(fr.index.to_numpy(dtype="int64"), hz)])
    return out


def failed_row(spec: RunSpec, err: BaseException) -> dict:
    """The row of a run whose task could not run at all (a worker died, the task was lost)."""
    row = C.empty_row()
    row.update(run_id=spec.run_id, source=spec.source, sha256=spec.sha256, vessel=spec.vessel or None)
    row.update(C.failure_columns("task", err))
    row["key"] = spec.key
    return row


__all__ = ["DEFAULT_SCENARIO", "DEFAULT_STAGES", "ESTIMATE_FILE", "HASH_CACHE", "LOG_FILE", "MAP_FILE", "MAP_HZ",
           "ROW_FILE", "RunSettings", "RunSpec", "STAGES", "Stages", "VESSEL_FILE", "content_sha256",
           "expand_sources", "failed_row", "finished_row", "make_spec", "map_log", "read_vessel_map", "run_key",
           "run_one", "source_hashes", "vessel_for"]
