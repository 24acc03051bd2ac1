"""Sample data, found the way scientific libraries find theirs: ``rovslam.data.path("sparus")``.

Each dataset is a registry entry (name, files with their SHA-256, licence, upstream address).
Its files live in a data folder, ``$ROVSLAM_DATA`` when that is set, else the platform's user
cache (``~/.cache/rovslam`` on Linux), laid out as ``DATA/NAME/FILE``. A file missing there is
taken, in this order, from:

1. a ``shared/data`` folder beside the checkout (or ``../shared/data`` from the current
   folder), copied into the data folder (the project's developers and CI have one);
2. its upstream address, downloaded with pooch and checked against its SHA-256 (datasets whose
   file is derived from the upstream one, e.g. cropped, have none: the error says so).

Every file is checked against its SHA-256 before it is used; a file that differs is never
returned. :func:`available` answers without downloading anything (for tests that skip).

The data are not rovslam's: each entry says where it comes from and under which terms.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

from rovslam.errors import DataNotFoundError

__all__ = ["DATASETS", "DATA_ENV", "Dataset", "available", "data_folder", "file_path", "path"]

DATA_ENV = "ROVSLAM_DATA"
DOWNLOAD_TIMEOUT_S = 30.0
_REPO_ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Dataset:
    """One sample dataset: its files (name -> SHA-256), where it comes from and on which terms."""

    name: str
    description: str
    files: dict[str, str] = field(default_factory=dict)
    licence: str = ""
    upstream: str = ""  # where it comes from (a page or repository at a commit)
    base_url: str | None = None  # where its files download from (None: derived, no download)


_MOSAIC_LIBRARY = "https://raw.githubusercontent.com/DTUAqua-ObsTek/mosaic-library/{commit}/tests/data/"

DATASETS: dict[str, Dataset] = {
    "sparus": Dataset(
        name="sparus",
        description="Sparus AUV (2013): 22 frames of real downward video over turbid sand, 384x288 at 5 fps, "
        "with the vehicle's navigation poses and the video's time offset",
        files={
            "sparus_snippet.mp4": "fa0625c09abcad639f6b83e064335bb800575436a68c700275a2bcd283ead034",
            "sparus_snippet.csv": "5c779feee23d1796b2dd17a24f9499cb74e911d9a5bcd3c8e9423d07970cf5ef",
            "sparus_time_offset.yaml": "bfb6b64b1d75966288d04f679361ed17e7c20fcb60556e1f292aabc7d3e40e6f",
        },
        licence="redistributed in the MIT-licensed mosaic-library's test data; the recording's own licence is "
        "not stated: for testing only",
        upstream="github.com/DTUAqua-ObsTek/mosaic-library, tests/data/",
        base_url=_MOSAIC_LIBRARY.format(commit="a5ba2d12928e12e97162db157412b0a108584740"),
    ),
    "chamber3": Dataset(
        name="chamber3",
        description="a real plan-view photomosaic of a rocky seabed (2288x2128 px, about 1 mm a pixel, "
        "uncalibrated), the seabed of the photo presets",
        files={"seabed.jpg": "d4f317ad28f5b17ac939c854e20e8f572250d0ce65931c4ae08832ceb47d1836"},
        licence="no licence stated for the data (the viewer's code is BSD/LGPL/MIT): for testing only",
        upstream="github.com/mattjr/seafloorexplore at 7e6298cc, chamber3/tiles_b1_level0 (cropped to the "
        "largest rectangle without no-data pixels)",
        base_url=None,
    ),
}

_verified: set[Path] = set()


def data_folder() -> Path:
    """The folder the datasets live in: ``$ROVSLAM_DATA``, else the platform's user cache for rovslam."""
    env = os.environ.get(DATA_ENV)
    if env:
        return Path(env).expanduser().absolute()
    import platformdirs

    return Path(platformdirs.user_cache_dir("rovslam"))


def _seed_folders() -> list[Path]:
    """Folders that may hold the datasets already (the project's shared data beside the checkout)."""
    seeds = [_REPO_ROOT.parent / "shared" / "data", Path.cwd().parent / "shared" / "data"]
    unique: list[Path] = []
    for s in seeds:
        s = s.resolve()
        if s not in unique and s.is_dir():
            unique.append(s)
    return unique


def _dataset(name: str) -> Dataset:
    if name not in DATASETS:
        raise DataNotFoundError(f"no dataset named {name!r}; the datasets are {', '.join(sorted(DATASETS))}.")
    return DATASETS[name]


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _good(path: Path, sha256: str) -> bool:
    """Whether ``path`` is a regular file with that SHA-256 (checked once a process)."""
    if path in _verified:
        return True
    if path.is_file() and _sha256(path) == sha256:
        _verified.add(path)
        return True
    return False


def _find_local(ds: Dataset, file: str) -> Path | None:
    """The file in the data folder, or copied there from a seed folder; None when neither has it."""
    sha = ds.files[file]
    target = data_folder() / ds.name / file
    if _good(target, sha):
        return target
    for seed in _seed_folders():
        candidate = seed / ds.name / file
        if not _good(candidate, sha):
            continue
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.with_name(f".{file}.part")
            shutil.copyfile(candidate, tmp)
            os.replace(tmp, target)
        except OSError:
            return candidate  # a read-only data folder: use the seed where it is
        return target if _good(target, sha) else candidate
    return None


def available(name: str) -> bool:
    """Whether every file of dataset ``name`` can be had without downloading anything."""
    ds = _dataset(name)
    return all(_find_local(ds, f) is not None for f in ds.files)


def file_path(name: str, file: str, *, download: bool = True) -> Path:
    """The verified local path of one file of dataset ``name`` (fetched if needed and allowed).

    Raises :class:`~rovslam.errors.DataNotFoundError` saying where it looked and how to get it.
    """
    ds = _dataset(name)
    if file not in ds.files:
        raise DataNotFoundError(f"dataset {name!r} has no file {file!r}; its files are {', '.join(sorted(ds.files))}.")
    found = _find_local(ds, file)
    if found is not None:
        return found
    folder = data_folder()
    how = (
        f"set {DATA_ENV} to a folder holding {name}/{file} (the project's shared data folder has it), "
        f"or put it at {folder / name / file}"
    )
    if ds.base_url is None or not download:
        why = (
            "it is derived from its upstream file and cannot be downloaded"
            if ds.base_url is None
            else "downloads are off"
        )
        raise DataNotFoundError(f"dataset {name!r}: {file} is not in {folder} ({why}); {how}.")
    return _download(ds, file, folder, how)


def _download(ds: Dataset, file: str, folder: Path, how: str) -> Path:
    import pooch

    try:
        got = pooch.retrieve(
            url=ds.base_url + file,  # type: ignore[operator]
            known_hash=f"sha256:{ds.files[file]}",
            fname=file,
            path=folder / ds.name,
            downloader=pooch.HTTPDownloader(timeout=DOWNLOAD_TIMEOUT_S, progressbar=False),
            progressbar=False,
        )
    except Exception as exc:  # noqa: BLE001 - network, HTTP, hash or disk: all say the same to the user
        raise DataNotFoundError(
            f"dataset {ds.name!r}: {file} is not in {folder} and could not be downloaded from {ds.base_url}{file} "
            f"({type(exc).__name__}: {exc}); {how}."
        ) from None
    return Path(got)


def path(name: str, *, download: bool = True) -> Path:
    """The local folder of dataset ``name`` with every one of its files verified (fetched if needed)."""
    ds = _dataset(name)
    paths = [file_path(name, f, download=download) for f in ds.files]
    folders = {p.parent for p in paths}
    if len(folders) == 1:
        return folders.pop()
    # Some files from a read-only seed, others from the data folder: the data folder gets them all.
    target = data_folder() / name
    for p in paths:
        if p.parent != target:
            target.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(p, target / p.name)
    return target
