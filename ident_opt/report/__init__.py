"""Reports: what the studies found, as Markdown, CSV, PNG and JSON, and the index of a results folder.

One writer per study (`identify`, `compare`, `constraints`, `audit`, `online`, `calibration`; the diagnosis
writes its own in `ident_opt.report.diagnosis`); `tables` and `figures` are their helpers. Every writer ends
with `record(out_dir, study, title, files)`: a small manifest (`.manifest/<study>.json` in the output folder)
says what the study wrote, and the folder's `README.md` is rebuilt from every manifest present — so the
index lists what is there whatever order the commands ran in. The folder's `index.html` (`report.html`) is
rebuilt beside it from the same manifests, with each study's `verdict` (optional, Markdown) first.

A study may also give the README a front part and a back part (`readme_head`, `readme_tail`: Markdown); the
identify report does (the reproduction table, findings, its tables, its figures). The other reports are listed
between them, in `ORDER`, each as its first file with its title.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ident_opt import outputs
from ident_opt.errors import InputError
from ident_opt.outputs import shown  # noqa: F401  (re-exported: every writer names its inputs so)
from ident_opt.report import html

#: Where the manifests live inside an output folder.
MANIFESTS = ".manifest"
#: The SHA-256 of the README.md the index last wrote (so that a README.md of the user's is never replaced).
README_DIGEST = f"{MANIFESTS}/README.md.sha256"
#: The order of the reports in the index (studies not listed follow, by name).
ORDER = ("audit", "compare", "constraints", "diagnosis", "confusion", "online", "online_benchmark", "calibration")


def record(
    out_dir: str | Path,
    study: str,
    title: str,
    files: Iterable[str | Path],
    *,
    readme_head: str = "",
    readme_tail: str = "",
    verdict: str = "",
) -> Path:
    """Note that `study` wrote `files` (relative to `out_dir`, or inside it; the main report first) under
    `title` (one line for the index), then rebuild the results folder's README.md. The results folder is
    `out_dir`, or its parent when that holds manifests too (so `results/diagnosis` is indexed in
    `results/README.md`); `out_dir`/index.html is rebuilt in either case. `verdict`: what a person needs first
    (Markdown, `report.verdicts`), at the top of the page. Returns the README's path."""
    out_dir = Path(out_dir)
    rel = [_relative(Path(f), out_dir) for f in files]
    manifest = {"study": study, "title": title, "files": rel, "readme_head": readme_head, "readme_tail": readme_tail}
    if verdict:
        manifest["verdict"] = verdict
    folder = out_dir / MANIFESTS
    check_folder(out_dir)
    outputs.write_text(folder / f"{study}.json", json.dumps(manifest, indent=1, ensure_ascii=False) + "\n")
    in_parent = (out_dir.parent / MANIFESTS).is_dir()
    own = write_index(out_dir) if _has_main(out_dir) or not in_parent else None
    parent = write_index(out_dir.parent) if in_parent else None
    if own is None:  # indexed in its parent's README, yet the folder the command wrote gets its page too
        _check_ours(out_dir, html.PAGE)
        _write_page(out_dir, _manifests(out_dir))
    return own or parent


def check_folder(out_dir: str | Path) -> None:
    """Before a report goes into `out_dir`: its `.manifest` (and its parent's, when that is a results folder too)
    a folder of well-formed manifests, and each README.md the index would replace one that ident-opt wrote
    (`_check_readme`); InputError naming the file otherwise. Nothing is written."""
    out_dir = Path(out_dir)
    folder = out_dir / MANIFESTS
    run = outputs.current()
    for path in run.outputs if run is not None else []:  # --json/--final onto the index this run writes
        if any(outputs.same_or_inside(path, out_dir / name) for name in ("README.md", html.PAGE, MANIFESTS)):
            raise InputError(
                f"{path}: the output folder {out_dir} keeps its index there (README.md, {html.PAGE}, {MANIFESTS}/); "
                "write this output elsewhere"
            )
    if folder.exists() and not folder.is_dir():
        raise InputError(
            f"{folder}: exists and is not a folder; ident-opt keeps the manifests of its reports in a folder of "
            "that name: move the file away or choose another --out"
        )
    in_parent = (out_dir.parent / MANIFESTS).is_dir()
    roots = ([out_dir] if _has_main(out_dir) or not in_parent else []) + ([out_dir.parent] if in_parent else [])
    for root in roots:
        _manifests(root)  # every manifest read (InputError naming a malformed one)
        _check_ours(root, "README.md")
        _check_ours(root, html.PAGE)
    _check_ours(out_dir, html.PAGE)  # written even when the index is its parent's


def _check_ours(root: Path, name: str) -> None:
    """`root`/`name` (README.md or index.html) may be replaced by the index: it is absent, or it is what
    ident-opt last wrote there (its SHA-256 in `.manifest/<name>.sha256`), or, a README.md with no digest kept
    (written by a version that kept none), the folder holds manifests already. A user's file is never replaced."""
    readme, digest = root / name, root / MANIFESTS / f"{name}.sha256"
    if not readme.exists():
        return
    if readme.is_dir() or not readme.is_file():
        raise InputError(f"{readme}: is not a file; ident-opt writes the folder's index there: move it away")
    if digest.is_file():
        ours = digest.read_text(encoding="utf-8", errors="replace").strip() == _sha256(readme)
    elif name == "README.md":
        ours = any((root / MANIFESTS).glob("*.json")) if (root / MANIFESTS).is_dir() else False
    else:
        ours = False
    if not ours:
        raise InputError(
            f"{readme}: exists and was not written by ident-opt (or was edited since); ident-opt writes the "
            "folder's index there: move it away or choose another --out"
        )


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _has_main(folder: Path) -> bool:
    """Whether `folder` holds a main report (a manifest with a README head or tail): it then has its own README
    (another robot's results, e.g. results/dfki), linked from the parent's instead of merged into it."""
    for path in folder.glob(f"{MANIFESTS}/*.json"):
        manifest = _load(path)
        if manifest.get("readme_head") or manifest.get("readme_tail"):
            return True
    return False


def write_index(root: Path) -> Path:
    """`root`/README.md and `root`/index.html from every manifest in `root` and its subfolders whose main file
    exists. Returns the README's path."""
    manifests = _manifests(root)
    main = [m for m in manifests if m["readme_head"] or m["readme_tail"]]
    others = [m for m in manifests if not (m["readme_head"] or m["readme_tail"])]
    parts = [m["readme_head"] for m in main if m["readme_head"]] or ["# Results"]
    if others:
        parts += ["", "Other reports in this folder:" if main else "Reports in this folder:", ""]
        parts += [f"- [{m['files'][0]}]({m['files'][0]}): {m['title']}" for m in others]
    parts += [m["readme_tail"] for m in main if m["readme_tail"]]
    path = root / "README.md"
    _check_ours(root, "README.md")
    _check_ours(root, html.PAGE)
    outputs.write_text(path, "\n".join(parts) + "\n")
    outputs.write_text(root / README_DIGEST, _sha256(path) + "\n")
    _write_page(root, manifests)
    return path


def _write_page(root: Path, manifests: list[dict]) -> None:
    """`root`/index.html (`report.html`) and its digest (so that the next run knows the page is its own)."""
    page = html.write_page(root, manifests)
    outputs.write_text(root / MANIFESTS / f"{html.PAGE}.sha256", _sha256(page) + "\n")


def _manifests(root: Path) -> list[dict]:
    """Every manifest in `root` and its subfolders, its files made relative to `root`, in `ORDER`; those whose
    main file is gone are left out."""
    found = []
    own_roots = {p.parent.parent for p in root.glob(f"*/{MANIFESTS}/*.json") if _has_main(p.parent.parent)}
    for sub in sorted(own_roots):
        head = next((m for m in map(_load, sub.glob(f"{MANIFESTS}/*.json")) if m.get("readme_head")), {})
        title = next(iter((head.get("readme_head") or "").splitlines()), "").lstrip("# ") or sub.name
        found.append(
            {
                "study": sub.name,
                "title": title,
                "files": [f"{sub.name}/README.md"],
                "readme_head": "",
                "readme_tail": "",
                "subfolder": True,  # a folder with its own README and page, linked from this one
            }
        )
    for path in [*root.glob(f"{MANIFESTS}/*.json"), *root.glob(f"*/{MANIFESTS}/*.json")]:
        if path.parent.parent in own_roots:
            continue
        manifest = _load(path)
        prefix = path.parent.parent.relative_to(root)
        manifest["files"] = [(prefix / f).as_posix() for f in manifest["files"]]
        if manifest["files"] and (root / manifest["files"][0]).exists():
            found.append(manifest)
    rank = {study: i for i, study in enumerate(ORDER)}
    return sorted(found, key=lambda m: (rank.get(m["study"], len(ORDER)), m["study"]))


#: The keys of a manifest and their types.
MANIFEST_KEYS = {"study": str, "title": str, "files": list, "readme_head": str, "readme_tail": str}
#: Keys a manifest may have (older manifests have none of them).
OPTIONAL_KEYS = {"verdict": str}


def _load(path: Path) -> dict:
    """A manifest, checked: a JSON object with `MANIFEST_KEYS` (files: names of files); InputError naming it."""
    fault = None
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        fault = f"cannot be read ({getattr(exc, 'strerror', None) or type(exc).__name__})"
    except ValueError as exc:
        fault = f"is not JSON ({exc})"
    else:
        wrong = [
            k
            for k, kind in MANIFEST_KEYS.items()
            if not isinstance(manifest, dict) or not isinstance(manifest.get(k), kind)
        ]
        wrong += [k for k, kind in OPTIONAL_KEYS.items() if not wrong and not isinstance(manifest.get(k, ""), kind)]
        if wrong or not all(isinstance(f, str) for f in manifest["files"]):
            fault = f"is not a manifest of ident-opt (key {(wrong or ['files'])[0]!r} missing or of the wrong type)"
    if fault:
        raise InputError(
            f"{path}: {fault}; ident-opt keeps one manifest per report in {MANIFESTS}/ to index the folder: "
            "remove the file (the next run of that report writes it again)"
        )
    return manifest


def _relative(path: Path, out_dir: Path) -> str:
    if path.is_absolute() or path.parts[: len(out_dir.parts)] == out_dir.parts:
        try:
            return path.resolve().relative_to(out_dir.resolve()).as_posix()
        except ValueError:
            raise ValueError(f"{path} is not inside the output folder {out_dir}") from None
    return path.as_posix()


def write_json(path: str | Path | None, payload: dict) -> None:
    """Write `payload` as strict JSON atomically (`outputs.write_text`): never half a file, never NaN or
    Infinity. NumPy scalars and arrays and paths are written as plain values; a non-finite number becomes
    null with a warning on standard error naming its keys. Nothing when `path` is None."""
    if not path:
        return
    try:  # the common case, in one pass: every number finite, every key a plain one (a fleet's JSON is megabytes)
        text = json.dumps(payload, indent=2, allow_nan=False, default=_plain)
    except (ValueError, TypeError):  # a non-finite number or a NumPy key somewhere: walk it, and name the keys
        clean, bad = strict(payload)
        if bad:
            shown_keys = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
            print(f"warning: {path}: {len(bad)} non-finite value(s) written as null: {shown_keys}", file=sys.stderr)
        text = json.dumps(clean, indent=2, allow_nan=False)
    outputs.write_text(path, text + "\n")


def strict(value: Any, where: str = "", bad: list[str] | None = None) -> tuple[Any, list[str]]:
    """`value` made of plain JSON types (NumPy values and paths converted), each non-finite number replaced by
    None; with the keys (`a.b[2]`) where that happened."""
    bad = [] if bad is None else bad
    value = _plain(value)
    if isinstance(value, dict):
        return {str(k): strict(v, f"{where}.{k}" if where else str(k), bad)[0] for k, v in value.items()}, bad
    if isinstance(value, (list, tuple)):
        return [strict(v, f"{where}[{i}]", bad)[0] for i, v in enumerate(value)], bad
    if isinstance(value, float) and not math.isfinite(value):
        bad.append(where or "(top level)")
        return None, bad
    return value, bad


def _plain(value: Any) -> Any:
    """JSON for NumPy scalars/arrays (both have `tolist`; NumPy itself is not imported for it) and paths."""
    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, (str, int, float, bool, dict, list, tuple)):
        return value
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
