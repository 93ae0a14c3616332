"""YAML input with line numbers, ``--set`` overrides and included files.

:func:`load_document` parses a workflow file into plain data (dicts, lists, scalars) and a map
from every field path to the file and line it came from, so that a validation error's location
(a pydantic ``loc`` such as ``('steps', 0, 'run', 'nsteps')``) becomes ``FILE.yaml:LINE``.

YAML details:

* numbers in exponent form without a dot (``2e9``) are numbers (YAML 1.2), not strings, and
  integral numbers (``1e3``, ``500.0``) are read as integers (accepted wherever a number is);
* a key given twice in one mapping is an error (PyYAML would silently keep the last one);
* ``--set a.b.c=VALUE`` overrides (VALUE parsed as YAML) are applied before validation; list items
  are addressed by index (``steps.0.nsteps``) or, for lists of named items, by name
  (``steps.oscillate.nsteps``);
* a material given as ``{file: PATH}`` is replaced by the YAML mapping in ``PATH`` (relative to the
  workflow file); its errors point into that file.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from geodem.workflow.errors import ErrorItem, WorkflowError, format_path


class _Loader(yaml.SafeLoader):
    """Safe loader that also reads ``1e9``-style numbers as floats."""


def _float(loader, node):
    """Floats as usual, but integral ones (``1e3``, ``500.0``) become ints: a count may be
    written ``1e6``, and a float field takes an int."""
    v = yaml.SafeLoader.construct_yaml_float(loader, node)
    if math.isfinite(v) and v == int(v) and abs(v) < 2**63:
        return int(v)
    return v


_Loader.add_constructor("tag:yaml.org,2002:float", _float)
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def parse_scalar(text: str):
    """Parse one YAML value (as in ``--set key=VALUE``)."""
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - _Loader is a SafeLoader


def _tag_named_like_a_key(cur: dict, loc: tuple, k: int) -> bool:
    """Whether ``loc[k]`` is a union tag that happens to be a key of ``cur`` too.

    A library material ``{library: NAME, use: ...}`` has the tag ``library``: pydantic's
    location of a bad ``use`` is ``(..., 'library', 'use')``, where ``library`` is the tag and
    ``use`` is the next key of the same mapping."""
    if k + 1 >= len(loc) or isinstance(cur[loc[k]], (dict, list)):
        return False
    return loc[k + 1] in cur


@dataclass
class Document:
    """Parsed input: ``data`` plus ``lines[path] = (file label, line or None)``."""

    data: Any
    file: str
    base_dir: Path
    lines: dict = field(default_factory=dict)

    # ------------------------------------------------------------------ locating errors
    def locate(self, loc, keep_last: bool = True) -> tuple[str | None, int | None, tuple]:
        """``(file, line, shown_loc)`` of a pydantic error location.

        Components that are not keys of the data (discriminated-union tags such as a step's
        kind) are dropped, except the last one when ``keep_last`` (a missing field's name)."""
        cur = self.data
        path: tuple = ()
        shown: list = []
        loc = tuple(loc)
        for k, comp in enumerate(loc):
            last = k == len(loc) - 1
            if isinstance(cur, dict) and comp in cur and not _tag_named_like_a_key(cur, loc, k):
                cur = cur[comp]
            elif isinstance(cur, list) and isinstance(comp, int) and 0 <= comp < len(cur):
                cur = cur[comp]
            elif last and keep_last:
                shown.append(comp)
                break
            else:
                continue  # a union tag, not part of the data
            path += (comp,)
            shown.append(comp)
        file, line = self.where(path)
        return file, line, tuple(shown)

    def where(self, path) -> tuple[str | None, int | None]:
        """File and line of ``path`` (or of its nearest recorded ancestor)."""
        path = tuple(path)
        while True:
            if path in self.lines:
                return self.lines[path]
            if not path:
                return self.file, None
            path = path[:-1]

    def error(self, loc, message: str, keep_last: bool = True) -> ErrorItem:
        file, line, shown = self.locate(loc, keep_last)
        return ErrorItem(file, line, format_path(shown), message)

    def get(self, path, default=None):
        cur = self.data
        for comp in path:
            if isinstance(cur, dict) and comp in cur:
                cur = cur[comp]
            elif isinstance(cur, list) and isinstance(comp, int) and 0 <= comp < len(cur):
                cur = cur[comp]
            else:
                return default
        return cur

    def _replace_lines(self, prefix, new: dict):
        n = len(prefix)
        for key in [k for k in self.lines if k[:n] == prefix]:
            del self.lines[key]
        self.lines.update(new)


# ---------------------------------------------------------------------- parsing
def _walk(node, path, label, lines, loader, errors):
    if isinstance(node, yaml.MappingNode):
        seen = {}
        for knode, vnode in node.value:
            try:
                key = loader.construct_object(knode, deep=True)
            except Exception:  # noqa: BLE001 - unhashable/complex keys: schema will complain
                key = knode.value
            kline = knode.start_mark.line + 1
            if isinstance(key, (list, dict)):
                key = str(key)
            if key in seen:
                errors.append(ErrorItem(label, kline, format_path(path + (key,)),
                                        f"key {key!r} given twice in one mapping (first on line "
                                        f"{seen[key]}); give it once"))
                continue
            seen[key] = kline
            lines[path + (key,)] = (label, kline)
            _walk(vnode, path + (key,), label, lines, loader, errors)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            lines[path + (i,)] = (label, item.start_mark.line + 1)
            _walk(item, path + (i,), label, lines, loader, errors)


def parse_text(text: str, label: str, prefix=()) -> tuple[Any, dict]:
    """Parse YAML ``text``; returns ``(data, lines)`` with lines keyed by ``prefix + path``."""
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None, {prefix: (label, 1)}
        data = loader.construct_document(node)
        lines = {prefix: (label, node.start_mark.line + 1)}
        errors: list = []
        _walk(node, prefix, label, lines, loader, errors)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        what = " ".join(str(p) for p in (exc.context, exc.problem) if p)
        raise WorkflowError(ErrorItem(label, line, "(YAML syntax)",
                                      f"{what or 'not valid YAML'}")) from None
    except yaml.YAMLError as exc:
        raise WorkflowError(ErrorItem(label, None, "(YAML syntax)", str(exc))) from None
    finally:
        loader.dispose()
    if errors:
        raise WorkflowError(errors)
    return data, lines


def read_text(path: Path, label: str, at: ErrorItem | None = None) -> str:
    try:
        return path.read_text()
    except FileNotFoundError:
        msg = f"file not found: {path}"
    except IsADirectoryError:
        msg = f"is a folder, not a file: {path}"
    except (OSError, UnicodeDecodeError) as exc:
        msg = f"cannot read {path}: {exc}"
    if at is not None:
        raise WorkflowError(ErrorItem(at.file, at.line, at.path, msg))
    raise WorkflowError(ErrorItem(label, None, "(file)", msg))


def load_document(path, sets=(), label: str | None = None) -> Document:
    """Read the workflow file ``path``, apply ``--set`` overrides and include material files."""
    path = Path(path)
    label = label or str(path)
    text = read_text(path, label)
    data, lines = parse_text(text, label)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise WorkflowError(ErrorItem(label, 1, "(top level)",
                                      f"a workflow is a mapping of keys (metadata, model, steps, "
                                      f"...), got {type(data).__name__}"))
    doc = Document(data, label, path.resolve().parent, lines)
    for expr in sets:
        apply_set(doc, expr)
    resolve_includes(doc)
    return doc


# ---------------------------------------------------------------------- overrides
def apply_set(doc: Document, expr: str) -> None:
    """Apply one ``KEY=VALUE`` override (``KEY`` dotted; list items by index or name)."""
    origin = f"--set {expr}"
    if "=" not in expr:
        raise WorkflowError(ErrorItem(origin, None, expr,
                                      "expected KEY=VALUE, e.g. --set steps.0.nsteps=1000 or "
                                      "--set model.diameter=0.02"))
    key, text = expr.split("=", 1)
    comps = [c for c in key.strip().split(".")]
    if not key.strip() or any(not c for c in comps):
        raise WorkflowError(ErrorItem(origin, None, key or "(empty)",
                                      "the key is a dotted path such as model.diameter"))
    try:
        value = parse_scalar(text)
    except yaml.YAMLError as exc:
        raise WorkflowError(ErrorItem(origin, None, key, f"value is not valid YAML: {exc}")) \
            from None
    cur = doc.data
    path: tuple = ()
    for k, comp in enumerate(comps):
        last = k == len(comps) - 1
        if isinstance(cur, list):
            idx = _list_index(cur, comp)
            if idx is None:
                from geodem.workflow.schema import default_names

                names = default_names((str(it.get("kind")), it.get("name")) for it in cur
                                      if isinstance(it, dict))
                raise WorkflowError(ErrorItem(
                    origin, None, format_path(path + (comp,)),
                    f"no list item {comp!r}: give an index 0..{len(cur) - 1}"
                    + (f" or a name ({', '.join(map(str, names))})" if names else "")))
            comp = idx
            if last:
                cur[comp] = value
            else:
                cur = cur[comp]
        elif isinstance(cur, dict):
            if last:
                cur[comp] = value
            else:
                if not isinstance(cur.get(comp), (dict, list)):
                    cur[comp] = {}
                cur = cur[comp]
        else:
            raise WorkflowError(ErrorItem(origin, None, format_path(path),
                                          "cannot set a key inside a value that is not a "
                                          "mapping or a list"))
        path += (comp,)
    doc._replace_lines(path, {path: (origin, None)})


def _list_index(items: list, comp: str):
    try:
        i = int(comp)
    except ValueError:
        from geodem.workflow.schema import default_names

        pairs = [(str(it.get("kind")), it.get("name") if isinstance(it.get("name"), str)
                  else None) if isinstance(it, dict) else ("?", None) for it in items]
        for i, name in enumerate(default_names(pairs)):
            if name == comp:
                return i
        return None
    return i if -len(items) <= i < len(items) else None


# ---------------------------------------------------------------------- includes
def resolve_includes(doc: Document) -> None:
    """Replace every ``materials.NAME: {file: PATH}`` by the mapping in ``PATH``."""
    mats = doc.data.get("materials")
    if not isinstance(mats, dict):
        return
    for name, spec in list(mats.items()):
        if not (isinstance(spec, dict) and set(spec) == {"file"} and isinstance(spec["file"], str)):
            continue
        at = doc.error(("materials", name, "file"), "")
        p = Path(spec["file"]).expanduser()
        if not p.is_absolute():
            p = doc.base_dir / p
        if not p.exists():
            raise WorkflowError(ErrorItem(at.file, at.line, at.path,
                                          f"file not found: {p} (a relative path is taken from "
                                          f"the workflow file's folder {doc.base_dir})"))
        label = str(p)
        text = read_text(p, label, at)
        prefix = ("materials", name)
        data, lines = parse_text(text, label, prefix)
        if not isinstance(data, dict):
            raise WorkflowError(ErrorItem(label, 1, format_path(prefix),
                                          "a material file holds a mapping (E, nu, Tu, Cu, mu_i, "
                                          "rho or rho, kn, ks, ...)"))
        mats[name] = data
        doc._replace_lines(prefix, lines)
