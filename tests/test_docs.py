"""The documentation site's generated pages: the configuration reference and the API pages."""

from __future__ import annotations

import dataclasses
import importlib.util
import re
import typing
from pathlib import Path

from rovslam import config

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _gen_pages():
    spec = importlib.util.spec_from_file_location("gen_pages", DOCS / "gen_pages.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_configuration_reference_lists_every_field_with_its_meaning():
    gen = _gen_pages()
    rows = gen.configuration_rows()
    expected = set()
    for table in dataclasses.fields(config.RunConfig):
        cls = typing.get_type_hints(config.RunConfig)[table.name]
        expected |= {(cls.TABLE, f.name) for f in dataclasses.fields(cls)}
    assert {(r["table"], r["key"]) for r in rows} == expected
    assert [r["key"] for r in rows if not r["meaning"].strip()] == []
    page = gen.configuration_page()
    for table, key in expected:
        assert f"`{key}`" in page and f"`[{table}]`" in page


def test_a_range_and_a_unit_are_read_from_the_field():
    rows = {(r["table"], r["key"]): r for r in _gen_pages().configuration_rows()}
    fine = rows[("bandpass", "sigma_fine_px")]
    assert fine["unit"] == "px" and fine["range"] == "> 0 and <= 100" and fine["default"] == "`1`"
    assert rows[("processing", "min_px_per_m")]["unit"] == "px/m"
    assert "'green'" in rows[("bandpass", "channel")]["range"]


def test_every_public_module_has_an_api_page():
    pages = dict(_gen_pages().reference_pages())
    src = Path(config.__file__).resolve().parent
    modules = [
        p
        for p in src.rglob("*.py")
        if not any(part.startswith("_") and part != "__init__.py" for part in p.relative_to(src).parts)
    ]
    assert len(pages) == len(modules) - 0  # __main__ files start with "_" and are left out
    assert pages["rovslam/config.md"] == "# `rovslam.config`\n\n::: rovslam.config\n"


HISTORY = re.compile(r"\bstops? [0-9]+|\bissue [0-9]+|this build|this stop|this session", re.IGNORECASE)


def test_the_readme_and_the_pages_speak_about_the_software_not_its_history():
    root = DOCS.parent
    readme = (root / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 400
    found = []
    for page in [root / "README.md", *sorted(DOCS.glob("*.md"))]:
        for number, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            if HISTORY.search(line):
                found.append(f"{page.name}:{number}: {line.strip()[:80]}")
    assert found == []
