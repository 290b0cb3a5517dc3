"""Griffe extension for the API reference: our Google-style docstrings, rendered as Markdown.

The docstrings of shinro_ctrl are Google-style with a few Sphinx habits. This
extension rewrites them in memory (the source is untouched) once the package
is loaded, so that mkdocstrings renders them well and strict builds stay
meaningful:

* grouped entries such as ``u_min, u_max: Input bounds.`` in ``Args:`` /
  ``Attributes:`` sections become one entry per name, so griffe matches each
  name against the signature (and still warns about names that are not in it);
* Sphinx roles (``:class:`~shinro_ctrl.sim.SimResult``` or ``:meth:`step```)
  are resolved the way Python resolves names, from the documented object's
  scope outwards. A role that names a public object of the package becomes an
  optional cross-reference (a link when the object is rendered on some page);
  ``Class.member`` is also looked up package-wide when it is unique (for
  names imported inside functions). Anything else (private helpers, other
  packages) becomes inline code; the roles that name nothing in the package
  are listed at INFO level;
* ``.. math::`` blocks become fenced ``latex`` code blocks and ``:math:``
  roles inline code (readable offline, no MathJax needed).

Cross-references written in Markdown (``[Plant][shinro_ctrl.plants.base.Plant]``)
are untouched and stay strict: a broken one fails ``mkdocs build --strict``.
"""

from __future__ import annotations

import logging
import re
from typing import Any

import griffe

_log = logging.getLogger("mkdocs.plugins.griffe_shinro")

_ROLE = re.compile(r":(?:py:)?(class|meth|func|data|attr|mod|exc|obj|const|math):`(~?)([^`]+)`")
_SECTIONS = re.compile(
    r"^(\s*)(Args|Arguments|Parameters|Params|Attributes|Keyword Args|Keyword Arguments|Other Parameters|Raises):\s*$"
)
_GROUP = re.compile(r"^(\s*)([A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)+)\s*(\([^)]*\))?\s*:(.*)$")
_EXTERNAL = ("numpy", "scipy", "casadi", "mujoco", "osqp", "control", "pytest", "matplotlib", "concurrent", "dask")
_NAMES_CONTINUED = re.compile(r"^\s*[A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)*\s*,\s*$")


def expand_grouped_entries(text: str) -> str:
    """One entry per name in argument and attribute sections (``a, b: text`` -> ``a: text`` and ``b: text``)."""
    lines = text.splitlines()
    out: list[str] = []
    section_indent: int | None = None
    entry_indent: int | None = None
    i = 0
    while i < len(lines):
        line = lines[i]
        indent = len(line) - len(line.lstrip())
        header = _SECTIONS.match(line)
        if header:
            section_indent, entry_indent = len(header.group(1)), None
            out.append(line)
            i += 1
            continue
        if section_indent is not None and line.strip() and indent <= section_indent:
            section_indent = None
        if section_indent is None or not line.strip():
            out.append(line)
            i += 1
            continue
        if entry_indent is None:
            entry_indent = indent
        if indent != entry_indent:  # a description line of the current entry
            out.append(line)
            i += 1
            continue
        # A name list may continue on the next line(s) when it ends with a comma.
        joined, j = line, i
        while _NAMES_CONTINUED.match(joined) and j + 1 < len(lines):
            j += 1
            joined = joined.rstrip() + " " + lines[j].strip()
        group = _GROUP.match(joined)
        if not group:
            out.append(line)
            i += 1
            continue
        lead, names, annotation, first = group.group(1), group.group(2), group.group(3), group.group(4)
        body: list[str] = []
        j += 1
        while j < len(lines) and (not lines[j].strip() or len(lines[j]) - len(lines[j].lstrip()) > len(lead)):
            body.append(lines[j])
            j += 1
        while body and not body[-1].strip():  # keep trailing blank lines outside the entry
            j -= 1
            body.pop()
        for name in (n.strip() for n in names.split(",")):
            out.append(f"{lead}{name}{' ' + annotation if annotation else ''}:{first}")
            out.extend(body)
        i = j
    return "\n".join(out)


def convert_math_blocks(text: str) -> str:
    """``.. math::`` plus its indented block -> a fenced ``latex`` code block at the same indentation."""
    lines = text.splitlines()
    out: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.strip() != ".. math::":
            out.append(line)
            i += 1
            continue
        lead = line[: len(line) - len(line.lstrip())]
        j = i + 1
        block: list[str] = []
        while j < len(lines) and (not lines[j].strip() or len(lines[j]) - len(lines[j].lstrip()) > len(lead)):
            block.append(lines[j])
            j += 1
        while block and not block[-1].strip():
            block.pop()
            j -= 1
        while block and not block[0].strip():
            block.pop(0)
        depth = min((len(b) - len(b.lstrip()) for b in block if b.strip()), default=0)
        out.append(f"{lead}```latex")
        out.extend(f"{lead}{b[depth:]}" if b.strip() else "" for b in block)
        out.append(f"{lead}```")
        i = j
    return "\n".join(out)


def _documented(obj: Any) -> bool:
    """Whether ``obj`` is public all the way down from the package (rendered by our filters)."""
    return not any(part.startswith("_") for part in obj.path.split("."))


def _lookup(scope: Any, name: str) -> Any | None:
    """The object ``name`` (dotted) means inside ``scope``, searching outwards like Python."""
    head, _, rest = name.partition(".")
    node = scope
    while node is not None:
        members = node.all_members if getattr(node, "is_class", False) else node.members
        if head in members:
            found = members[head]
            try:
                for part in rest.split(".") if rest else ():
                    found = found.final_target if found.is_alias else found
                    members = found.all_members if found.is_class else found.members
                    found = members[part]
                return found.final_target if found.is_alias else found
            except (KeyError, griffe.AliasResolutionError, griffe.CyclicAliasError):
                return None
        node = node.parent
    return None


class ShinroDocstrings(griffe.Extension):
    """Rewrites every docstring of the loaded package (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__()
        self.unresolved: set[tuple[str, str]] = set()

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        if pkg.name != "shinro_ctrl":
            return
        self.index: list[Any] = []
        self._collect(pkg, set())
        self._visit(pkg, loader, set())
        for where, role in sorted(self.unresolved):
            _log.info("griffe_shinro: %s: %s names nothing in shinro_ctrl; shown as code", where, role)

    def _collect(self, obj: Any, seen: set[str]) -> None:
        if obj.path in seen:
            return
        seen.add(obj.path)
        self.index.append(obj)
        for member in obj.members.values():
            if not member.is_alias:
                self._collect(member, seen)

    def _unique_suffix(self, target: str) -> Any | None:
        """The one object of the package whose path ends with ``.target`` (None if none or several)."""
        hits = [o for o in self.index if o.path.endswith("." + target)]
        return hits[0] if len(hits) == 1 else None

    def _visit(self, obj: Any, loader: griffe.GriffeLoader, seen: set[str]) -> None:
        if obj.path in seen:
            return
        seen.add(obj.path)
        if obj.docstring is not None:
            obj.docstring.value = self.rewrite(obj.docstring.value, obj, loader)
        for member in obj.members.values():
            if not member.is_alias:
                self._visit(member, loader, seen)

    def rewrite(self, text: str, obj: Any, loader: griffe.GriffeLoader) -> str:
        """The Markdown form of one docstring."""
        text = convert_math_blocks(expand_grouped_entries(text))
        return _ROLE.sub(lambda m: self._role(m, obj, loader), text)

    def _role(self, match: re.Match[str], obj: Any, loader: griffe.GriffeLoader) -> str:
        kind, tilde, target = match.group(1), match.group(2), match.group(3).strip()
        if kind == "math":
            return f"`{target}`"
        shown = target.rsplit(".", 1)[-1] if tilde else target
        if target.startswith("shinro_ctrl."):
            try:
                found = loader.modules_collection.get_member(target)
                found = found.final_target if found.is_alias else found
            except (KeyError, ValueError, griffe.AliasResolutionError, griffe.CyclicAliasError):
                found = None
        else:
            found = _lookup(obj if obj.is_class or obj.is_module else obj.parent, target)
            if found is None and not (obj.is_class or obj.is_module):
                found = _lookup(obj, target)
            if found is None and "." in target:  # Class.member named from a module that imports it lazily
                found = self._unique_suffix(target)
        if found is None:
            if not target.startswith(_EXTERNAL):
                self.unresolved.add((obj.path, match.group(0)))
            return f"`{shown}`"
        if not _documented(found):
            return f"`{shown}`"
        return f'<autoref identifier="{found.path}" optional><code>{shown}</code></autoref>'
