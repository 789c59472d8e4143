"""The show file and every file it (and the rig) names, kept with the run: which show ran.

:func:`record_show_files` writes ``show_files.json`` into the run directory: one entry per file
(the show file; the sounds, animations and clips' files it names; the files the rig's targets
name) with its path, size and sha256, and where its copy is. A file up to
:data:`COPY_MAX_BYTES` is copied into ``show_files/`` (its name prefixed with its entry's number,
so two ``take.csv`` from different folders do not collide); a bigger one is hashed only (the
entry says so). The rig file itself is already in the run directory as ``rig.toml`` (the text
that was loaded, written by the telemetry writer); its entry names that copy.

Files are found by their keys, as the readers read them: ``file`` (every target source, a
sound's table) and ``voice`` (a lip-sync track's recording) anywhere in the file, and each
``[sounds]`` value; a name is relative to the file that names it. A name that is not a file is
left out (the show's own check has refused it already). Nothing here stops a show: an error
is returned as one line for the caller to say.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hilsim.targets.sources import rig_file
from hilsim.telemetry.format import CONFIG_NAME, SHOW_MANIFEST, to_json

#: files up to this size are copied into the run directory; bigger ones are hashed only
COPY_MAX_BYTES = 4 * 1024 * 1024
COPY_DIR = "show_files"
#: the keys whose text names a file, wherever they are
FILE_KEYS = ("file", "voice")


def named_files(doc: dict[str, Any], base_dir: Path, where: str) -> Iterator[tuple[str, Path]]:
    """``(key path, file)`` for each existing file the parsed TOML ``doc`` names (module
    docstring), relative to ``base_dir``; ``where`` starts each key path."""

    def walk(node: Any, key: str) -> Iterator[tuple[str, str]]:
        if isinstance(node, dict):
            for k, v in node.items():
                sub = f"{key}.{k}" if key else str(k)
                if isinstance(v, str) and (k in FILE_KEYS or key == "sounds"):
                    yield sub, v
                else:
                    yield from walk(v, sub)
        elif isinstance(node, list):
            for i, v in enumerate(node):
                yield from walk(v, f"{key}[{i}]")

    seen: set[Path] = set()
    for key, name in walk(doc, ""):
        path = rig_file(base_dir, name)
        if path.is_file() and path not in seen:
            seen.add(path)
            yield f"{where}: {key}", path


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            h.update(block)
    return h.hexdigest()


def _entry(run_dir: Path, n: int, role: str, named_by: str, path: Path) -> dict[str, Any]:
    size = path.stat().st_size
    entry: dict[str, Any] = {
        "role": role,
        "named_by": named_by,
        "path": str(path),
        "size": size,
        "sha256": _sha256(path),
        "copy": None,
    }
    if size <= COPY_MAX_BYTES:
        copy = Path(COPY_DIR) / f"{n:02d}-{path.name}"
        shutil.copyfile(path, run_dir / copy)
        entry["copy"] = str(copy)
    else:
        entry["why_not_copied"] = f"over {COPY_MAX_BYTES // (1024 * 1024)} MiB: hashed only"
    return entry


def _doc(path: Path) -> dict[str, Any]:
    with open(path, "rb") as f:
        return tomllib.load(f)


def record_show_files(
    run_dir: Path, rig_path: Path | None, rig_text: str | None, show_path: Path | None
) -> tuple[dict[str, Any] | None, str | None]:
    """Write ``show_files.json`` (and the copies) into ``run_dir``: the manifest, and None; or
    None and why it could not (one line: a disk error, a file gone since it was read)."""
    try:
        (run_dir / COPY_DIR).mkdir(exist_ok=True)
        files: list[dict[str, Any]] = []
        if rig_text is not None:
            files.append(
                {
                    "role": "rig",
                    "named_by": "hilsim run",
                    "path": None if rig_path is None else str(Path(rig_path).resolve()),
                    "size": len(rig_text.encode("utf-8")),
                    "sha256": hashlib.sha256(rig_text.encode("utf-8")).hexdigest(),
                    "copy": CONFIG_NAME,  # the text loaded, written by the telemetry writer
                }
            )
        named: list[tuple[str, str, Path]] = []
        if show_path is not None:
            show_path = Path(show_path).resolve()
            named.append(("show", "hilsim run --show", show_path))
            where = show_path.name
            named += [
                ("named", k, p) for k, p in named_files(_doc(show_path), show_path.parent, where)
            ]
        if rig_path is not None and rig_text is not None:
            rig_doc = tomllib.loads(rig_text)
            where = Path(rig_path).name
            named += [
                ("named", k, p) for k, p in named_files(rig_doc, Path(rig_path).parent, where)
            ]
        for role, named_by, path in named:
            files.append(_entry(run_dir, len(files), role, named_by, path))
        manifest = {"copy_max_bytes": COPY_MAX_BYTES, "files": files}
        tmp = run_dir / f".{SHOW_MANIFEST}.tmp"
        tmp.write_text(to_json(manifest, indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, run_dir / SHOW_MANIFEST)
    except (OSError, ValueError) as exc:  # the show comes first: said, never fatal
        return None, f"{SHOW_MANIFEST} not written: {exc}"
    return manifest, None
