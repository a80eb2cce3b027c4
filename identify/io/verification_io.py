"""The ``.verify.yaml`` an ``acquire verify`` run wrote, read for ``identify --report --verification`` (no numerics).

A verification vouches for one result file: its summary names it (``result``, the path given to ``acquire
verify``) and fingerprints it (``result_sha256``). A report may show the verification only when that file is
still there, unchanged, and is a calibration of the data the report is made from (its ``source``); anything else
is refused in one line naming both, before any computing.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import yaml

from common.errors import InputError


def read_verification(path: str) -> dict[str, Any]:
    """The summary at ``path`` (AP/RP per pose before and after, m); InputError (one line) when it is none."""
    try:
        doc = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"--verification {path}: cannot be read ({type(exc).__name__})") from None
    if not isinstance(doc, dict) or not {"runs", "verdict"} <= set(doc):
        raise InputError(f"--verification {path}: not the .verify.yaml of an acquire verify run")
    return doc


def load_verification(path: str, data: str) -> dict[str, Any]:
    """The summary at ``path``, checked to verify a calibration of the measurements ``data`` (a CSV or session
    path); InputError (one line) when it is no summary or vouches for another result."""
    doc = read_verification(path)
    named, sha = doc.get("result"), doc.get("result_sha256")
    if not named or not sha:
        raise InputError(f"--verification {path} does not name the result it verified (made before results were "
                         "named): run acquire verify --resume on its session to write it again")
    result = _find(str(named), Path(path).parent)
    if result is None:
        raise InputError(f"--verification {path} verified {named}, which is not there any more: it cannot vouch "
                         f"for the calibration of {data}")
    if hashlib.sha256(result.read_bytes()).hexdigest() != sha:
        raise InputError(f"--verification {path} verified an earlier {result}: the file has changed since; verify "
                         f"the calibration of {data} again")
    try:
        written = yaml.safe_load(result.read_text(encoding="utf-8")) or {}
        source, source_path = written.get("source"), written.get("source_path")
    except (OSError, UnicodeDecodeError, yaml.YAMLError, AttributeError):
        source = source_path = None
    if source is None or not _same([str(p) for p in (source_path, source) if p], data, result.parent):
        raise InputError(f"--verification {path} verified {result} (a calibration of {source or 'unknown data'}), "
                         f"not a calibration of {data}: refused")
    return doc


def _find(named: str, beside: Path) -> Path | None:
    """The result file ``named`` (as given to acquire verify: absolute, or relative to where it ran, which may be
    the summary's folder)."""
    for candidate in (Path(named), beside / named, beside / Path(named).name):
        if candidate.is_file():
            return candidate
    return None


def _same(sources: list[str], data: str, beside: Path) -> bool:
    """Whether a result's ``sources`` (its ``source_path``, absolute, and its ``source`` as typed, relative to
    where identify ran: here, or the result's folder ``beside`` or one above it) are the file ``data``: the same
    file (inode), however either path is spelled."""
    from common.outputs import same_file

    folders = [Path.cwd(), beside, *beside.resolve().parents]
    candidates = [Path(s) if Path(s).is_absolute() else folder / s for s in sources for folder in folders]
    candidates += [beside / Path(s).name for s in sources]  # the data moved with its result
    return any(c.exists() and same_file(c, data) for c in candidates)
