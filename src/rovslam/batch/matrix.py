"""The matrix file of ``rovslam batch``: which dives to run, each a cell (scenario x seed, or a sequence).

Format (TOML; paths relative to the matrix file)::

    name = "smoke"                   # optional, free text
    seeds = [0, 1]                   # default seeds of every [[scenario]]; or a count: seeds = 10 (0..9)
    config = "my-config.toml"        # optional: rovslam configuration of every cell (default: the paper's)

    [[scenario]]                     # one or more: a simulator preset (`rovslam simulate --list`)
    name = "portofino-short"
    frames = 200                     # optional: the first N frames of the preset's dive
    # duration_s = 300               # optional instead of frames: N = duration x the preset's frame rate
    # seeds = [3, 4]                 # optional: this scenario's seeds
    # config = "other.toml"          # optional: this scenario's configuration
    # label = "portofino-other-cfg"  # optional: the row name (default the scenario's), to run a preset twice
    # format = "jpg"                 # optional: image files of the simulated dive, png (default) or jpg
    # calibration_errors = true      # optional: draw each seed's lasting sensor errors (rovslam.sim.calibration)
    # relief_scale = 2.0             # optional: every height of the preset's relief times this (0: flat)

    [[sequence]]                     # zero or more: a recorded dive with ground truth
    name = "my-dive"                 # the cell's name
    path = "../dives/my-dive"        # a sequence folder (format v1)
    # groundtruth = "truth.csv"      # optional, default PATH/groundtruth.csv
    # frames = 1000                  # optional: the first N frames
    # config = "other.toml"

A scenario cell is named ``<label>_s<seed>``, a sequence cell ``<name>``. Everything is checked
when the file is loaded (unknown keys and scenarios, seeds, frames, configuration files), so a
typo stops the batch before any cell runs; sequence paths are checked by the cell itself,
since the workers of a cluster may see other paths than the client.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rovslam.config import RunConfig, load_config
from rovslam.errors import ConfigError, parse_toml

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_TOP_KEYS = ("name", "seeds", "config", "smooth", "scenario", "sequence")
_SCENARIO_KEYS = (
    "name",
    "frames",
    "duration_s",
    "seeds",
    "config",
    "label",
    "format",
    "calibration_errors",
    "relief_scale",
)
_SEQUENCE_KEYS = ("name", "path", "groundtruth", "frames", "config")


@dataclass(frozen=True)
class CellSpec:
    """One dive of the matrix: everything a worker needs to simulate, run and evaluate it."""

    cell_id: str  # folder name under DIR/cells/
    group: str  # the row of the summary table: the scenario label or the sequence name
    scenario: str | None = None  # simulator preset; None for a recorded sequence
    seed: int | None = None
    frames: int | None = None  # frames to simulate (scenario) or to run (sequence); None: all
    sequence_path: str | None = None  # recorded sequence folder (absolute)
    groundtruth_path: str | None = None
    config: RunConfig = RunConfig()
    config_path: str | None = None  # where ``config`` came from (None: the paper's defaults)
    image_format: str = "png"  # of the simulated images: png, or jpg (about a third of the cost in HD)
    smooth: bool = True  # also smooth the run (GTSAM iSAM2) and evaluate the smoothed path
    calibration_errors: bool = False  # simulate with the seed's drawn compass / laser-rig / sonar errors
    relief_scale: float = 1.0  # every height of the preset's relief times this (0: a flat seabed)

    @property
    def simulated(self) -> bool:
        return self.scenario is not None


@dataclass(frozen=True)
class Matrix:
    """A loaded, validated matrix file."""

    path: Path
    name: str
    cells: tuple[CellSpec, ...]

    @property
    def groups(self) -> tuple[str, ...]:
        """The summary rows, in file order."""
        return tuple(dict.fromkeys(c.group for c in self.cells))


def load_matrix(path: str | Path, scenarios: dict[str, Any] | None = None) -> Matrix:
    """Read and validate a matrix file. ``scenarios``: the known presets (default :data:`rovslam.sim.SCENARIOS`).

    Raises :class:`~rovslam.errors.ConfigError` naming the file, the entry and the key.
    """
    if scenarios is None:
        from rovslam.sim import SCENARIOS as scenarios
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: matrix file not found. Give a TOML file (see matrices/smoke.toml).")
    try:
        data = parse_toml(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    _check_keys(data, _TOP_KEYS, f"{p}")
    base = p.parent
    configs: dict[str, tuple[RunConfig, str | None]] = {}
    default_cfg = _config(data.get("config"), base, f"{p}: config", configs)
    default_seeds = _seeds(data.get("seeds", [0]), f"{p}: seeds")
    smooth = data.get("smooth", True)
    if not isinstance(smooth, bool):
        raise ConfigError(f"{p}: smooth must be true or false, got {smooth!r}")
    cells: list[CellSpec] = []
    for i, entry in enumerate(_tables(data, "scenario", p)):
        where = f"{p}: [[scenario]] #{i + 1}"
        _check_keys(entry, _SCENARIO_KEYS, where)
        name = entry.get("name")
        if name not in scenarios:  # type: ignore[operator]
            raise ConfigError(f"{where}: unknown scenario {name!r}; known: {', '.join(scenarios)}")  # type: ignore[arg-type]
        label = _name(entry.get("label", name), f"{where}: label")
        frames = _frames(entry, scenarios[name], where)  # type: ignore[index]
        cfg, cfg_path = (
            _config(entry.get("config"), base, f"{where}: config", configs) if "config" in entry else default_cfg
        )
        seeds = _seeds(entry["seeds"], f"{where}: seeds") if "seeds" in entry else default_seeds
        fmt = entry.get("format", "png")
        if fmt not in ("png", "jpg"):
            raise ConfigError(f'{where}: format must be "png" or "jpg", got {fmt!r}')
        calibration = entry.get("calibration_errors", False)
        if not isinstance(calibration, bool):
            raise ConfigError(f"{where}: calibration_errors must be true or false, got {calibration!r}")
        relief_scale = _relief_scale(entry, scenarios[name], where)  # type: ignore[index]
        cells += [
            CellSpec(
                f"{label}_s{s}",
                label,
                scenario=name,
                seed=s,
                frames=frames,
                config=cfg,
                config_path=cfg_path,
                image_format=fmt,
                smooth=smooth,
                calibration_errors=calibration,
                relief_scale=relief_scale,
            )
            for s in seeds
        ]
    for i, entry in enumerate(_tables(data, "sequence", p)):
        where = f"{p}: [[sequence]] #{i + 1}"
        _check_keys(entry, _SEQUENCE_KEYS, where)
        name = _name(entry.get("name"), f"{where}: name")
        if not isinstance(entry.get("path"), str) or not entry["path"]:
            raise ConfigError(f"{where}: path must be the sequence folder (a string), got {entry.get('path')!r}")
        seq = (base / entry["path"]).resolve()
        gt = entry.get("groundtruth")
        if gt is not None and not isinstance(gt, str):
            raise ConfigError(f"{where}: groundtruth must be a path (a string), got {gt!r}")
        frames = _positive_int(entry["frames"], f"{where}: frames") if "frames" in entry else None
        cfg, cfg_path = (
            _config(entry.get("config"), base, f"{where}: config", configs) if "config" in entry else default_cfg
        )
        cells.append(
            CellSpec(
                name,
                name,
                frames=frames,
                sequence_path=str(seq),
                groundtruth_path=str((base / gt).resolve() if gt else seq / "groundtruth.csv"),
                config=cfg,
                config_path=cfg_path,
                smooth=smooth,
            )
        )
    if not cells:
        raise ConfigError(f"{p}: no cells; add a [[scenario]] or a [[sequence]] table.")
    seen: set[str] = set()
    for c in cells:
        if c.cell_id in seen:
            raise ConfigError(f"{p}: cell {c.cell_id!r} appears twice; give one of the entries a different label/name.")
        seen.add(c.cell_id)
    name = data.get("name", p.stem)
    if not isinstance(name, str):
        raise ConfigError(f"{p}: name must be a string, got {name!r}")
    return Matrix(p, name, tuple(cells))


def _tables(data: dict, key: str, p: Path) -> list[dict]:
    entries = data.get(key, [])
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise ConfigError(f"{p}: {key} must be an array of tables, written [[{key}]]")
    return entries


def _relief_scale(entry: dict, scenario: Any, where: str) -> float:
    """The entry's ``relief_scale`` (default 1), checked against the preset's relief."""
    from rovslam.errors import SimulationError
    from rovslam.sim.relief import scaled_relief

    value = entry.get("relief_scale", 1.0)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where}: relief_scale must be a number >= 0, got {value!r}")
    try:
        scaled_relief(getattr(scenario, "relief", None), float(value))
    except SimulationError as exc:
        raise ConfigError(f"{where}: relief_scale: {exc}") from None
    return float(value)


def _check_keys(table: dict, allowed: Iterable[str], where: str) -> None:
    for key in table:
        if key not in allowed:
            raise ConfigError(f"{where}: unknown key {key!r}; allowed: {', '.join(allowed)}")


def _name(value: Any, where: str) -> str:
    if not isinstance(value, str) or not _NAME_RE.match(value):
        raise ConfigError(f"{where}: must be a name of letters, digits, '.', '_' or '-' (a folder name), got {value!r}")
    return value


def _positive_int(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{where}: must be a whole number >= 1, got {value!r}")
    return value


def _frames(entry: dict, scenario: Any, where: str) -> int | None:
    if "frames" in entry and "duration_s" in entry:
        raise ConfigError(f"{where}: give frames or duration_s, not both")
    if "frames" in entry:
        n = _positive_int(entry["frames"], f"{where}: frames")
    elif "duration_s" in entry:
        d = entry["duration_s"]
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not math.isfinite(d) or d <= 0:
            raise ConfigError(f"{where}: duration_s must be a positive number of seconds, got {d!r}")
        n = d * scenario.frame_rate_hz
    else:
        return None
    from rovslam.sim.scenarios import MAX_FRAMES  # loaded already: the scenario is one of its presets

    if n > MAX_FRAMES:  # 1e12 frames asked 149 GiB and failed in the worker; 1e308 s overflowed
        raise ConfigError(
            f"{where}: {n:.3g} frames to simulate, more than the {MAX_FRAMES:,} a cell may "
            f"hold ({MAX_FRAMES / scenario.frame_rate_hz / 3600:.0f} h of this preset); "
            "give a shorter duration_s or fewer frames"
        )
    return max(1, round(n))


MAX_SEEDS = 10_000  # per entry: a count beyond this is a typo (a billion seeds would fill the memory first)


def _seeds(value: Any, where: str) -> tuple[int, ...]:
    if isinstance(value, (int, list)) and not isinstance(value, bool):
        n = value if isinstance(value, int) else len(value)
        if n > MAX_SEEDS:
            raise ConfigError(
                f"{where}: {n} seeds, more than the {MAX_SEEDS} a matrix entry may hold; "
                "give a smaller count (seeds = 10 runs seeds 0 to 9)."
            )
    if isinstance(value, int) and not isinstance(value, bool):
        value = list(range(_positive_int(value, where)))
    if (
        not isinstance(value, list)
        or not value
        or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in value)
    ):
        raise ConfigError(f"{where}: must be a list of whole numbers >= 0 or a count >= 1, got {value!r}")
    if len(set(value)) != len(value):
        raise ConfigError(f"{where}: a seed appears twice in {value!r}")
    return tuple(value)


def _config(
    value: Any, base: Path, where: str, cache: dict[str, tuple[RunConfig, str | None]]
) -> tuple[RunConfig, str | None]:
    if value is None:
        return RunConfig(), None
    if not isinstance(value, str):
        raise ConfigError(f"{where}: must be the path of a configuration TOML file, got {value!r}")
    path = str((base / value).resolve())
    if path not in cache:
        try:
            cache[path] = (load_config(path), path)
        except ConfigError as exc:  # it names the configuration file and key; add the matrix entry
            raise ConfigError(f"{where}: {exc}") from None
    return cache[path]
