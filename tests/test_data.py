"""Sample data through rovslam.data: the data folder, seeding from the shared data, checksums, downloads."""

from __future__ import annotations

import functools
import hashlib
import http.server
import threading

import pytest

from rovslam import data
from rovslam.errors import DataNotFoundError

PAYLOAD = b"seabed bytes " * 1000
SHA = hashlib.sha256(PAYLOAD).hexdigest()


@pytest.fixture
def toy(tmp_path, monkeypatch):
    """A registry of one dataset ``toy`` (one file), an empty data folder and no seed folder."""
    ds = data.Dataset(name="toy", description="test", files={"a.bin": SHA}, base_url=None)
    monkeypatch.setitem(data.DATASETS, "toy", ds)
    monkeypatch.setattr(data, "_seed_folders", lambda: [])
    monkeypatch.setattr(data, "_verified", set())
    monkeypatch.setenv(data.DATA_ENV, str(tmp_path / "cache"))
    return ds


def test_a_file_in_the_data_folder_is_found_after_its_checksum(toy, tmp_path):
    assert not data.available("toy")
    (tmp_path / "cache" / "toy").mkdir(parents=True)
    (tmp_path / "cache" / "toy" / "a.bin").write_bytes(PAYLOAD)
    assert data.available("toy")
    assert data.path("toy") == tmp_path / "cache" / "toy"
    assert data.file_path("toy", "a.bin").read_bytes() == PAYLOAD


def test_a_file_that_differs_from_its_checksum_is_never_used(toy, tmp_path):
    (tmp_path / "cache" / "toy").mkdir(parents=True)
    (tmp_path / "cache" / "toy" / "a.bin").write_bytes(PAYLOAD[:-1] + b"!")
    assert not data.available("toy")
    with pytest.raises(DataNotFoundError, match="derived"):
        data.file_path("toy", "a.bin")


def test_the_data_folder_is_seeded_from_the_shared_data(toy, tmp_path, monkeypatch):
    seed = tmp_path / "shared" / "data"
    (seed / "toy").mkdir(parents=True)
    (seed / "toy" / "a.bin").write_bytes(PAYLOAD)
    monkeypatch.setattr(data, "_seed_folders", lambda: [seed])
    got = data.file_path("toy", "a.bin")
    assert got == tmp_path / "cache" / "toy" / "a.bin"  # copied into the data folder
    assert got.read_bytes() == PAYLOAD


def test_a_missing_dataset_says_where_it_looked_and_how_to_get_it(toy, tmp_path):
    with pytest.raises(DataNotFoundError) as info:
        data.file_path("toy", "a.bin")
    msg = str(info.value)
    assert str(tmp_path / "cache") in msg and data.DATA_ENV in msg and "toy/a.bin" in msg
    with pytest.raises(DataNotFoundError, match="no dataset named 'nope'"):
        data.path("nope")
    with pytest.raises(DataNotFoundError, match="has no file 'b.bin'"):
        data.file_path("toy", "b.bin")


def _serve(folder):
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def test_a_dataset_with_an_upstream_is_downloaded_and_checked(toy, tmp_path, monkeypatch):
    (tmp_path / "upstream").mkdir()
    (tmp_path / "upstream" / "a.bin").write_bytes(PAYLOAD)
    server = _serve(tmp_path / "upstream")
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/"
        monkeypatch.setitem(
            data.DATASETS, "toy", data.Dataset(name="toy", description="t", files={"a.bin": SHA}, base_url=url)
        )
        assert not data.available("toy")  # available() never downloads
        got = data.file_path("toy", "a.bin")
        assert got.read_bytes() == PAYLOAD and got.parent == tmp_path / "cache" / "toy"
        assert data.available("toy")
        # An upstream file that changed is refused by its checksum.
        (tmp_path / "upstream" / "b.bin").write_bytes(b"not the file")
        monkeypatch.setitem(
            data.DATASETS, "bad", data.Dataset(name="bad", description="t", files={"b.bin": SHA}, base_url=url)
        )
        with pytest.raises(DataNotFoundError, match="could not be downloaded"):
            data.file_path("bad", "b.bin")
        assert not (tmp_path / "cache" / "bad" / "b.bin").exists()
    finally:
        server.shutdown()
        server.server_close()


def test_the_registry_names_its_sources_and_terms():
    for ds in data.DATASETS.values():
        assert ds.files and ds.licence and ds.upstream and ds.description
        assert all(len(sha) == 64 for sha in ds.files.values())
