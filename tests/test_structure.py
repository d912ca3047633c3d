"""The shape of the code (issue 15, items 3, 4 and 6): no import cycles among the project's modules, every
import of ours names a module that exists, no module over 600 lines, dependencies only in the allowed
direction, and every citation of ``docs/design.md`` names a heading that exists there (none cites the
upper-case design document kept outside the repository).

The import graph is read from the source with ``ast`` (nothing is imported), so imports inside
functions, under ``TYPE_CHECKING`` and in ``try`` blocks count like the ones at the top: a reader
depends on them either way. What makes an edge from module ``m``:

- ``import a.b.c`` / ``from a.b import c``: an edge to the longest project module naming the target
  (``a.b.c`` when that file exists, else ``a.b``, else ``a``); ``from pkg import name`` is an edge to
  the submodule ``pkg.name`` where that file exists, else to ``pkg``. Relative imports resolve
  against ``m``'s package.
- Importing ``a.b.c`` also runs the ``__init__`` of ``a`` and ``a.b``: an edge to each of those
  packages too, except a package that contains ``m`` itself (Python has begun importing it before
  ``m`` runs, so naming a sibling by its absolute path adds no dependency; an explicit
  ``from a import name`` of that package still counts as an edge).
- ``importlib.import_module("a.b")`` and ``__import__("a.b")`` with a literal name: an edge, as
  if imported (the lazy import hides the dependency, it does not remove it).
- A string ``"a.b:Name"`` whose module part is a project module (the entry-point form a registry
  keeps to import lazily): an edge from the module holding the registry to ``a.b``.
"""
from __future__ import annotations

import ast
import functools
import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("tissuerender", "sim", "postfx", "materials")
MAX_LINES = 600
# top-level package -> the top-level packages of ours it may import (docs/design.md, "Architecture")
ALLOWED_DEPENDENCIES = {
    "tissuerender": {"sim", "postfx", "materials"},
    "sim": {"materials"},
    "postfx": set(),
    "materials": set(),
}
DESIGN_DOC = "docs/design.md"
SCANNED_SUFFIXES = {".py", ".md", ".toml", ".rst", ".txt"}


@dataclass(frozen=True)
class Edge:
    source: str
    target: str
    path: str  # relative to the root
    line: int
    kind: str  # "import", "package" (a parent package's __init__), "dynamic", "registry"

    def __str__(self):
        return f"{self.source} -> {self.target} ({self.path}:{self.line}, {self.kind})"


# --- the module graph ---------------------------------------------------------------------------------------


def project_modules(root: Path, packages=PACKAGES) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` under the given top-level packages."""
    modules = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def _package_of(module: str, path: Path) -> list[str]:
    """The package a relative import in ``module`` is relative to, as parts."""
    parts = module.split(".")
    return parts if path.name == "__init__.py" else parts[:-1]


def _resolve_relative(name: str, level: int, package: list[str]) -> str | None:
    if level == 0:
        return name
    if level - 1 > len(package):
        return None
    base = package[: len(package) - (level - 1)]
    return ".".join(base + ([name] if name else [])) or None


def _longest_module(name: str, modules) -> str | None:
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


_ENTRY_POINT = re.compile(r"^([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*):[A-Za-z_]\w*$")


def _targets(node: ast.AST, module: str, package: list[str], modules) -> list[tuple[str, str]]:
    """(dotted target, kind) pairs that one AST node imports."""
    if isinstance(node, ast.Import):
        return [(alias.name, "import") for alias in node.names]
    if isinstance(node, ast.ImportFrom):
        stem = _resolve_relative(node.module or "", node.level, package)
        if stem is None:
            return []
        return [(f"{stem}.{a.name}" if f"{stem}.{a.name}" in modules else stem, "import") for a in node.names]
    if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
            and isinstance(node.args[0].value, str):
        func = node.func
        fname = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
        if fname in ("import_module", "__import__"):
            name = node.args[0].value
            level = len(name) - len(name.lstrip("."))
            resolved = _resolve_relative(name.lstrip("."), level, package)
            return [(resolved, "dynamic")] if resolved else []
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        match = _ENTRY_POINT.match(node.value)
        if match and match.group(1).split(".")[0] in {m.split(".")[0] for m in modules}:
            return [(match.group(1), "registry")]
    return []


@dataclass(frozen=True)
class ImportSite:
    module: str
    path: str  # relative to the root
    line: int
    name: str  # the dotted module the statement names (``from X import a``: X.a where that is a module, else X)
    kind: str


def import_sites(root: Path, modules: dict[str, Path]) -> list[ImportSite]:
    """Every import of the given modules, as written (resolved relative names, not yet matched to files)."""
    sites = []
    for module, path in modules.items():
        package = _package_of(module, path)
        rel = path.relative_to(root).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            sites += [ImportSite(module, rel, node.lineno, name, kind)
                      for name, kind in _targets(node, module, package, modules)]
    return sites


def unresolved_imports(root: Path, modules: dict[str, Path]) -> list[ImportSite]:
    """Imports naming a module of our packages that has no file (a stale path after a move; an import
    inside a function or a registry string fails only when it runs)."""
    ours = {m.split(".")[0] for m in modules}
    bad = {s for s in import_sites(root, modules) if s.name.split(".")[0] in ours and s.name not in modules}
    return sorted(bad, key=lambda s: (s.path, s.line, s.name))


def import_edges(root: Path, modules: dict[str, Path]) -> list[Edge]:
    """Every dependency edge between project modules (see the module docstring for what counts)."""
    edges = []
    for site in import_sites(root, modules):
        module = site.module
        target = _longest_module(site.name, modules)  # a module that has no file counts as its package
        if target is None:
            continue  # not ours
        if target != module:
            edges.append(Edge(module, target, site.path, site.line, site.kind))
        # the __init__ of every package on the way, except one that contains `module`
        parts = target.split(".")
        for i in range(1, len(parts)):
            parent = ".".join(parts[:i])
            if parent in modules and parent != module and not module.startswith(parent + "."):
                edges.append(Edge(module, parent, site.path, site.line, "package"))
    return edges


def strongly_connected_cycles(nodes, edges: list[Edge]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    graph = {n: [] for n in nodes}
    for e in edges:
        graph.setdefault(e.source, []).append(e.target)
        graph.setdefault(e.target, [])
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(set(graph[start]))))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(set(graph[w])))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return sorted(found)


def describe_cycles(cycles: list[list[str]], edges: list[Edge]) -> str:
    lines = []
    for component in cycles:
        members = set(component)
        lines.append("cycle: " + ", ".join(component))
        seen = set()
        for e in sorted(edges, key=lambda e: (e.source, e.target, e.line)):
            if e.source in members and e.target in members and (e.source, e.target) not in seen:
                seen.add((e.source, e.target))
                lines.append(f"    {e}")
    return "\n".join(lines)


def long_modules(modules: dict[str, Path], root: Path, limit: int = MAX_LINES) -> list[tuple[str, int]]:
    """(path, line count) of every module over ``limit`` lines."""
    out = []
    for path in modules.values():
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > limit:
            out.append((path.relative_to(root).as_posix(), n))
    return sorted(out)


def direction_violations(edges: list[Edge], allowed=ALLOWED_DEPENDENCIES) -> list[Edge]:
    """Edges from one top-level package to another that the dependency direction forbids."""
    bad = []
    for e in edges:
        src, dst = e.source.split(".")[0], e.target.split(".")[0]
        if src != dst and dst not in allowed.get(src, set()):
            bad.append(e)
    return bad


# --- references to docs/design.md ---------------------------------------------------------------------------


def _normalise(text: str) -> str:
    text = text.replace("\u2013", "-").replace("\u2014", "-").replace("\u2011", "-")
    return " ".join(text.split()).casefold()


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def headings(markdown: str) -> list[str]:
    """The ATX headings of a Markdown text, outside fenced code blocks."""
    out, fenced = [], False
    for line in markdown.splitlines():
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
            continue
        match = None if fenced else re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if match:
            out.append(match.group(1))
    return out


# `docs/design.md#anchor`, or `docs/design.md, "Heading"` (also `: "..."`, `("...")`, `section "..."`, and with the
# quoted heading on the next comment line); a bare `docs/design.md` names no section and is tolerated.
# Inside docs/ a relative `design.md#anchor` link is a reference too.
_REFERENCE = re.compile(
    r"(?P<file>(?:docs/|\./|(?<![\w/.]))design\.md)"
    r"(?:#(?P<anchor>[\w\-]+)"
    r"|[ \t]*[,:]?[ \t]*(?:\n[ \t]*(?:#|//|\*|>)?[ \t]*)?(?:section[ \t]+)?\(?[\"\u201c](?P<name>[^\s\"\u201d][^\"\u201d]{0,200})[\"\u201d])"
)
_CONTINUATION = re.compile(r"\n[ \t]*(?:#|//|\*|>)?[ \t]*")


def design_references(root: Path, skip=()) -> list[tuple[str, int, str, str]]:
    """(path, line, "anchor" | "heading", text) of every section reference to docs/design.md."""
    refs = []
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root)
        if path.suffix not in SCANNED_SUFFIXES or not path.is_file() or path in skip:
            continue
        if any(part.startswith(".") or part in ("__pycache__", "node_modules") for part in rel.parts):
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        in_docs = rel.parts[0] == "docs"
        for match in _REFERENCE.finditer(text):
            if match.group("file") != "docs/design.md" and not in_docs:
                continue  # a relative design.md link only means ours inside docs/
            line = text.count("\n", 0, match.start()) + 1
            if match.group("anchor"):
                refs.append((rel.as_posix(), line, "anchor", match.group("anchor")))
            elif match.group("name"):
                refs.append((rel.as_posix(), line, "heading", _CONTINUATION.sub(" ", match.group("name"))))
    return refs


def missing_design_sections(root: Path, skip=()) -> list[str]:
    """'file:line: ...' for each reference whose heading or anchor is not in docs/design.md."""
    design = root / DESIGN_DOC
    names = headings(design.read_text(encoding="utf-8")) if design.exists() else []
    anchors = {slug(h) for h in names}
    normalised = [_normalise(h) for h in names]
    missing = []
    for path, line, kind, text in design_references(root, skip):
        if kind == "anchor":
            if text not in anchors:
                missing.append(f"{path}:{line}: no heading with anchor #{text} in {DESIGN_DOC}")
            continue
        want = _normalise(text)
        # the full heading, or its start up to a word boundary ("Zhang ch. 5: EBM" for the EBM section)
        if not any(h == want or (h.startswith(want) and not h[len(want)].isalnum()) for h in normalised):
            missing.append(f'{path}:{line}: no heading "{text}" in {DESIGN_DOC}')
    return missing


def outside_design_citations(root: Path, skip=()) -> list[str]:
    """'file:line' of each citation of the design document kept outside the repository (upper case)."""
    pattern = re.compile(r"DESIGN" r"\.md")
    out = []
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root)
        if path.suffix not in SCANNED_SUFFIXES or not path.is_file() or path in skip:
            continue
        if any(part.startswith(".") or part in ("__pycache__", "node_modules") for part in rel.parts):
            continue
        for n, text in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if pattern.search(text):
                out.append(f"{rel.as_posix()}:{n}: {text.strip()}")
    return out


# --- the project's own tree ---------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1)
def _project_graph():
    modules = project_modules(ROOT)
    return modules, import_edges(ROOT, modules)


def test_no_import_cycles():
    modules, edges = _project_graph()
    cycles = strongly_connected_cycles(modules, edges)
    assert not cycles, f"{len(cycles)} import cycle(s) among the project's modules:\n" + describe_cycles(cycles, edges)


def test_every_import_of_ours_names_an_existing_module():
    modules, _ = _project_graph()
    bad = unresolved_imports(ROOT, modules)
    assert not bad, "imports of project modules that do not exist:\n" + "\n".join(
        f"    {s.path}:{s.line}: {s.name} ({s.kind})" for s in bad)


def test_no_module_over_600_lines():
    modules, _ = _project_graph()
    too_long = long_modules(modules, ROOT)
    assert not too_long, f"modules over {MAX_LINES} lines:\n" + "\n".join(f"    {p}: {n} lines" for p, n in too_long)


def test_dependencies_point_the_allowed_way():
    _, edges = _project_graph()
    bad = direction_violations(edges)
    assert not bad, ("imports against tissuerender -> (sim, postfx, materials), sim -> materials "
                     "(docs/design.md, \"Architecture\"):\n" + "\n".join(f"    {e}" for e in bad))


def test_design_md_references_name_existing_headings():
    assert (ROOT / DESIGN_DOC).exists(), f"{DESIGN_DOC} is missing"
    missing = missing_design_sections(ROOT, skip={Path(__file__).resolve()})
    assert not missing, "references to missing sections:\n" + "\n".join(f"    {m}" for m in missing)


def test_no_citation_of_a_design_document_outside_the_repository():
    cites = outside_design_citations(ROOT, skip={Path(__file__).resolve()})
    assert not cites, ("cite docs/design.md and its section instead of the upper-case design document "
                       "outside the repository:\n" + "\n".join(f"    {c}" for c in cites))


# --- each checker catches a planted violation --------------------------------------------------------------


def _write(root: Path, files: dict[str, str]):
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def _synthetic_graph(root: Path, packages=("app", "lib")):
    modules = project_modules(root, packages)
    edges = import_edges(root, modules)
    return modules, edges, strongly_connected_cycles(modules, edges)


def test_cycle_checker_sees_function_level_relative_and_from_package_imports(tmp_path):
    _write(tmp_path, {
        "app/__init__.py": "from . import a\n",                   # relative `from . import submodule`
        "app/a.py": "def f():\n    from app import b\n",          # inside a function, from pkg import submodule
        "app/b.py": "from .sub import c\n",                       # relative, into a subpackage
        "app/sub/__init__.py": "",
        "app/sub/c.py": "import app.a\n",                         # absolute dotted import closes the loop
        "lib/__init__.py": "",
        "lib/d.py": "import numpy\nimport app.sub.c\n",           # not ours; not in a cycle
    })
    _, edges, cycles = _synthetic_graph(tmp_path)
    # app/__init__ reaches the cycle but is not on it: app.sub.c's `import app.a` runs its own package first
    assert cycles == [["app.a", "app.b", "app.sub.c"]]
    assert Edge("lib.d", "app", "lib/d.py", 2, "package") in edges  # importing app.sub.c runs app/__init__


def test_cycle_checker_sees_dynamic_and_registry_imports(tmp_path):
    _write(tmp_path, {
        "app/__init__.py": "",
        "app/registry.py": 'REGISTRY = {"x": "app.solver:Solver"}\n',
        "app/solver.py": "from app.registry import REGISTRY\n",
        "app/pipe.py": "import importlib\n\ndef r():\n    return importlib.import_module('app.render')\n",
        "app/render.py": "def call():\n    from app.pipe import r\n",
    })
    _, edges, cycles = _synthetic_graph(tmp_path, ("app",))
    assert cycles == [["app.pipe", "app.render"], ["app.registry", "app.solver"]]
    assert {e.kind for e in edges if e.source in ("app.registry", "app.pipe")} == {"registry", "dynamic"}


def test_cycle_checker_counts_a_parent_package_init_but_not_the_importers_own_package(tmp_path):
    _write(tmp_path, {
        # a package re-exporting its submodules, which name their siblings by absolute path: no cycle
        "app/__init__.py": "from app.x import X\n",
        "app/x.py": "import app.y\nX = 1\n",
        "app/y.py": "",
        # lib.p imports lib.q.r, which runs lib/q/__init__, which imports lib.p: a cycle through the __init__
        "lib/__init__.py": "",
        "lib/p.py": "import lib.q.r\n",
        "lib/q/__init__.py": "from lib import p\n",
        "lib/q/r.py": "",
    })
    _, _, cycles = _synthetic_graph(tmp_path)
    assert cycles == [["lib.p", "lib.q"]]


def test_cycle_checker_reports_a_three_module_cycle_with_its_edges(tmp_path):
    _write(tmp_path, {
        "app/__init__.py": "",
        "app/bodies.py": "from app.scene import Scene\n",
        "app/scene/__init__.py": "from app.scene.load import load\nScene = 1\n",
        "app/scene/load.py": "def load():\n    from app.bodies import build\n",
    })
    _, edges, cycles = _synthetic_graph(tmp_path, ("app",))
    assert cycles == [["app.bodies", "app.scene", "app.scene.load"]]
    report = describe_cycles(cycles, edges)
    assert "app.scene.load -> app.bodies (app/scene/load.py:2, import)" in report


def test_unresolved_checker_names_stale_imports_registry_strings_and_dynamic_names(tmp_path):
    _write(tmp_path, {
        "app/__init__.py": "import numpy\nfrom app import there\n",
        "app/there.py": "from app.there import NAME\nNAME = 1\n",
        "app/moved.py": ("def f():\n    from app.old import g, h\n"
                         "R = {'x': 'app.gone:Solver', 'y': 'app.there:NAME'}\n"
                         "import importlib\nimportlib.import_module('app.missing')\n"),
    })
    modules = project_modules(tmp_path, ("app",))
    bad = [(s.path, s.line, s.name, s.kind) for s in unresolved_imports(tmp_path, modules)]
    assert bad == [("app/moved.py", 2, "app.old", "import"), ("app/moved.py", 3, "app.gone", "registry"),
                           ("app/moved.py", 5, "app.missing", "dynamic")]


def test_size_checker_names_a_planted_long_module(tmp_path):
    _write(tmp_path, {"app/__init__.py": "", "app/big.py": "x = 1\n" * (MAX_LINES + 1), "app/ok.py": "x = 1\n" * MAX_LINES})
    modules = project_modules(tmp_path, ("app",))
    assert long_modules(modules, tmp_path) == [("app/big.py", MAX_LINES + 1)]


def test_direction_checker_names_each_planted_violation(tmp_path):
    _write(tmp_path, {
        "tissuerender/__init__.py": "import sim, postfx, materials\n",
        "sim/__init__.py": "import materials\n",
        "sim/bad.py": "def f():\n    from postfx import tonemap\n",
        "postfx/__init__.py": "",
        "postfx/tonemap.py": "from materials import optics\n",
        "materials/__init__.py": "",
        "materials/optics.py": "import importlib\nimportlib.import_module('sim')\n",
    })
    modules = project_modules(tmp_path)
    bad = {(e.source, e.target) for e in direction_violations(import_edges(tmp_path, modules))}
    assert bad == {("sim.bad", "postfx.tonemap"), ("sim.bad", "postfx"), ("postfx.tonemap", "materials.optics"),
                   ("postfx.tonemap", "materials"), ("materials.optics", "sim")}


def test_reference_checker_names_file_line_and_missing_heading(tmp_path):
    _write(tmp_path, {
        "docs/design.md": "# Design\n\n## The plan\n\n```\n## not a heading\n```\n\n"
                          "### Zhang ch. 5: EBM (5.7, 5.8, 5.10/5.11, 5.15)\n",
        "docs/other.md": "See [the plan](design.md#the-plan) and [gone](design.md#gone).\n",
        "app/__init__.py": (
            '"""Bare docs/design.md is fine. (Zhang 5.10 corrected: docs/design.md, "Zhang ch. 5: EBM")\n'
            'docs/design.md#zhang-ch-5-ebm-57-58-510511-515 and docs/design.md, "Zhang ch. 5: EB"."""\n'
            '# a wrapped one: docs/design.md,\n#   "The plan"; a missing one: docs/design.md, "Not here"\n'
            '# in a code block: docs/design.md, "not a heading"\n'
            '# parenthesised: docs/design.md ("The plan") and docs/design.md ("Gone")\n'
        ),
    })
    missing = missing_design_sections(tmp_path)
    assert missing == [
        'app/__init__.py:2: no heading "Zhang ch. 5: EB" in docs/design.md',
        'app/__init__.py:4: no heading "Not here" in docs/design.md',
        'app/__init__.py:5: no heading "not a heading" in docs/design.md',
        'app/__init__.py:6: no heading "Gone" in docs/design.md',
        "docs/other.md:1: no heading with anchor #gone in docs/design.md",
    ]
    _write(tmp_path, {"app/old.py": "# see " + "DESIGN" + ".md\n"})
    assert outside_design_citations(tmp_path) == ["app/old.py:1: # see " + "DESIGN" + ".md"]
