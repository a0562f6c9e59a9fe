"""docs/architecture.md names modules and packages that exist (its picture and tables match the code)."""

import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = (ROOT / "docs" / "architecture.md").read_text()
#: top-level folders (and the root package) a dotted name in the page may start from
TOPS = ("analysis", "acquisition", "drivers", "configs", "monitor", "cli", "runfile", "estimators")


def _module_of(dotted: str) -> str | None:
    """The longest prefix of ``dotted`` that is an importable module or package (None if none)."""
    parts = dotted.split(".")
    for k in range(len(parts), 1, -1):
        try:
            if importlib.util.find_spec(".".join(parts[:k])) is not None:
                return ".".join(parts[:k])
        except ModuleNotFoundError:
            continue
    return None


def test_dotted_names_and_paths_exist():
    spans = set(re.findall(r"`([^`\s]+)`", DOC)) | set(re.findall(r"<b>([\w.]+)</b>", DOC))
    dotted = {s for s in spans if re.fullmatch(r"(imustation\.)?(" + "|".join(TOPS) + r")(\.\w+)*", s)}
    assert len(dotted) > 20
    missing = []
    for d in sorted(dotted):
        full = d if d.startswith("imustation") else f"imustation.{d}"
        full = full.replace("imustation.estimators.", "imustation.analysis.estimators.")  # short form in the text
        mod = _module_of(full)
        # a name past the module must be an attribute of it (a function, a constant)
        rest = full[len(mod) + 1 :].split(".") if mod and mod != full else []
        if mod is None or (rest and not hasattr(importlib.import_module(mod), rest[0])):
            missing.append(d)
    assert not missing, f"docs/architecture.md names what does not exist: {missing}"
    paths = {s.split(":")[0] for s in spans if re.fullmatch(r"[\w/]+\.py(:\w+)?", s)}
    assert paths and not [p for p in paths if not (ROOT / p).exists()]


def _members(folder: Path) -> set[str]:
    """Module and package names anywhere below ``folder`` (files without .py, folders with ``/``)."""
    out = {p.stem for p in folder.rglob("*.py")}
    return (
        out
        | {p.name for p in folder.rglob("*") if p.is_dir()}
        | {p.name + "/" for p in folder.rglob("*") if p.is_dir()}
    )


def test_every_module_the_picture_and_the_rooms_table_list_exists():
    # the diagram: "<b>room</b><br/>a · b · c" lists modules or packages (x/) of that room
    for room, listed in re.findall(r"<b>([\w. ()]+)</b><br/>([^\"]+)\"", DOC):
        name = "imustation" if room.startswith("kernel") else room.split(" ")[0]
        folder = Path(
            importlib.util.find_spec(name if name.startswith("imustation") else f"imustation.{name}").origin
        ).parent
        items = [i.strip() for i in re.split(r"·|<br/>", listed)]
        modules = [i for i in items if re.fullmatch(r"\w+/?", i)]
        if name in ("imustation.cli", "drivers"):
            continue  # described in words ("parse options", "one module per chip")
        assert modules, room
        missing = [m for m in modules if m not in _members(folder)]
        assert not missing, f"diagram room {room} lists {missing}, which are not modules there"
    # the rooms table: every `name` in a row's "holds" cell is a module or package under its folder
    rows = re.findall(r"^\| `([\w/]+)/`[^|]*\|[^|]*\| (.+) \|$", DOC, flags=re.M)
    assert len(rows) >= 6
    for folder, holds in rows:
        names = [n for n in re.findall(r"`([\w/]+)`", holds) if re.fullmatch(r"\w+/?", n)]
        missing = [n for n in names if n not in _members(ROOT / folder)]
        assert not missing, f"rooms table row {folder}/ names {missing}, which are not modules there"
