"""Pages generated when the documentation is built (mkdocs-gen-files).

* ``configuration.md``: every field of every configuration table, from the dataclasses of
  ``rovslam.config`` and the comments written beside each field (meaning, unit, default, range).
* ``reference/``: one API page per module of ``src/rovslam`` (mkdocstrings), with its navigation.

Run by ``mkdocs build``; ``python docs/gen_pages.py`` prints the configuration page instead.
"""

from __future__ import annotations

import ast
import dataclasses
import math
import re
import sys
import typing
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
if str(SRC) not in sys.path:
    sys.path.insert(0, str(SRC))

UNITS = {
    "_px_per_m": "px/m",
    "_px2": "px²",
    "_px": "px",
    "_m2": "m²",
    "_m": "m",
    "_mm": "mm",
    "_cm": "cm",
    "_s": "s",
    "_ms": "ms",
    "_hz": "Hz",
    "_mps2": "m/s²",
    "_mps": "m/s",
    "_rad2": "rad²",
    "_radps": "rad/s",
    "_rad": "rad",
    "_deg": "degree",
    "_per_s2": "1/s²",
    "_per_s": "1/s",
    "_frames": "frames",
}


def unit_of(name: str) -> str:
    """The unit a field's name carries (rovslam names units as suffixes), '' when none."""
    for suffix in sorted(UNITS, key=len, reverse=True):
        if name.endswith(suffix):
            return UNITS[suffix]
    return ""


def field_comments(source: str) -> dict[tuple[str, str], str]:
    """(class, field) -> the comment written beside the field or in the lines just above it."""
    lines = source.splitlines()
    out: dict[tuple[str, str], str] = {}
    for node in ast.parse(source).body:
        if not isinstance(node, ast.ClassDef):
            continue
        for item in node.body:
            if not (isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name)):
                continue
            text = []
            k = item.lineno - 2
            while k >= 0 and lines[k].strip().startswith("#"):
                text.insert(0, lines[k].strip().lstrip("#").strip())
                k -= 1
            end = lines[item.end_lineno - 1]
            if "#" in end:
                code, _, comment = end.partition("  #")
                if comment:
                    text.append(comment.strip())
            out[(node.name, item.target.id)] = " ".join(t for t in text if t)
        out.update(_docstring_attributes(node))
    return out


def _docstring_attributes(node: ast.ClassDef) -> dict[tuple[str, str], str]:
    """The ``Attributes:`` section of a class docstring (Google style): (class, field) -> text."""
    doc = ast.get_docstring(node) or ""
    if "Attributes:" not in doc:
        return {}
    out: dict[tuple[str, str], str] = {}
    key = None
    for line in doc.split("Attributes:", 1)[1].splitlines():
        m = re.match(r"^    (\w+): (.*)$", line)
        if m:
            key = m.group(1)
            out[(node.name, key)] = m.group(2).strip()
        elif key and line.startswith("        "):
            out[(node.name, key)] += " " + line.strip()
        elif line.strip():
            key = None
    return out


def _range(meta: typing.Mapping[str, object]) -> str:
    parts = []
    if meta.get("gt") is not None:
        parts.append(f"> {meta['gt']:g}")
    if meta.get("ge") is not None:
        parts.append(f">= {meta['ge']:g}")
    if meta.get("le") is not None:
        parts.append(f"<= {meta['le']:g}")
    return " and ".join(parts)


def _type_text(tp: object) -> tuple[str, str]:
    """(type, allowed values) of a field's annotation."""
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        return "choice", ", ".join(f"`{a!r}`" for a in typing.get_args(tp))
    if origin is not None and origin is not typing.Literal:
        names, allowed = [], []
        for a in typing.get_args(tp):
            n, al = _type_text(a)
            names.append(n)
            if al:
                allowed.append(al)
        return " or ".join(names), ", ".join(allowed)
    return getattr(tp, "__name__", str(tp)), ""


def _default_text(value: object) -> str:
    if isinstance(value, bool):
        return "`true`" if value else "`false`"
    if isinstance(value, float):
        return f"`{value:g}`" if math.isfinite(value) else f"`{value}`"
    return f"`{value!r}`" if isinstance(value, str) else f"`{value}`"


def configuration_rows() -> list[dict[str, str]]:
    """One row per configuration field: table, key, type, unit, default, range, meaning."""
    from rovslam import config

    comments = field_comments((SRC / "rovslam" / "config.py").read_text(encoding="utf-8"))
    rows = []
    for table_field in dataclasses.fields(config.RunConfig):
        cls = typing.get_type_hints(config.RunConfig)[table_field.name]
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            kind, allowed = _type_text(hints[f.name])
            rng = _range(f.metadata)
            rows.append(
                {
                    "table": cls.TABLE,
                    "class": cls.__name__,
                    "key": f.name,
                    "type": kind,
                    "unit": unit_of(f.name),
                    "default": _default_text(getattr(cls(), f.name)),
                    "range": " ; ".join(p for p in (rng, allowed) if p),
                    "meaning": comments.get((cls.__name__, f.name), ""),
                }
            )
    return rows


def configuration_page() -> str:
    from rovslam import config

    out = [
        "# Configuration reference",
        "",
        "Every setting of a run, table by table, as `rovslam config` writes them and `--config FILE` reads",
        "them (TOML, one table per stage). Each value is checked when the file is loaded: its type, its",
        "range, its choices; an unknown table or key is refused. The defaults are the paper's figures where",
        "it gives them. This page is generated from `rovslam.config` when the documentation is built.",
        "",
    ]
    rows = configuration_rows()
    for table_field in dataclasses.fields(config.RunConfig):
        cls = typing.get_type_hints(config.RunConfig)[table_field.name]
        doc = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
        out += [
            f"## `[{cls.TABLE}]`",
            "",
            doc,
            "",
            "| key | type | unit | default | allowed | meaning |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for r in rows:
            if r["class"] == cls.__name__:
                meaning = r["meaning"].replace("|", "\\|")
                out.append(f"| `{r['key']}` | {r['type']} | {r['unit']} | {r['default']} | {r['range']} | {meaning} |")
        out.append("")
    return "\n".join(out)


def reference_pages() -> list[tuple[str, str]]:
    """(page path under reference/, page text) for every public module, the package's tree."""
    pages = []
    for path in sorted((SRC / "rovslam").rglob("*.py")):
        rel = path.relative_to(SRC).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__main__" or any(p.startswith("_") and p != "__init__" for p in parts):
            continue
        if parts[-1] == "__init__":
            parts = parts[:-1]
            doc = Path(*parts, "index.md")
        else:
            doc = Path(*parts).with_suffix(".md")
        ident = ".".join(parts)
        pages.append((doc.as_posix(), f"# `{ident}`\n\n::: {ident}\n"))
    return pages


def _build() -> None:
    import mkdocs_gen_files

    with mkdocs_gen_files.open("configuration.md", "w") as fh:
        fh.write(configuration_page())
    nav = mkdocs_gen_files.Nav()
    for doc, text in reference_pages():
        parts = tuple(Path(doc).with_suffix("").parts)
        if parts[-1] == "index":
            parts = parts[:-1]
        nav[parts] = doc
        with mkdocs_gen_files.open(f"reference/{doc}", "w") as fh:
            fh.write(text)
    with mkdocs_gen_files.open("reference/SUMMARY.md", "w") as fh:
        fh.writelines(nav.build_literate_nav())


if __name__ == "__main__":
    print(configuration_page())
elif __name__ == "<run_path>":  # mkdocs-gen-files runs this file with runpy.run_path
    _build()
