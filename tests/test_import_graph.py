"""The package's import graph keeps data flowing one way:
source -> decode -> align -> supervise/learn -> pipeline -> store/report -> live service -> API -> CLI.

Read from the source (every import statement, also those inside functions), so a
lazy import against the flow is caught as well as a top-level one.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "service" / "vdp"

# Stage of each module (longest prefix wins).  A module may import its own stage or an
# earlier one.  Stage 0 is what every stage shares: errors, channel names, config, and
# the plain data types that travel along the flow (Sample, Estimate, RunResult).
STAGE = {
    "vdp.errors": 0,
    "vdp.channels": 0,
    "vdp.settings": 0,
    "vdp.profile": 0,
    "vdp.units": 0,  # the profile's units table
    "vdp.opendbc": 0,  # finds (and repairs, caches) a profile's opendbc DBC
    "vdp.core.params": 0,
    "vdp.core.result": 0,
    "vdp.core.sample": 0,
    "vdp.result": 0,
    "vdp.io.dbcfix": 0,  # repairs DBC text as a profile is loaded
    "vdp.text": 0,  # names escaped for the formats they go into (the standard library only)
    "vdp.outfile": 0,  # every user file written whole (temporary file, rename; the standard library only)
    "vdp.io.logs": 1,  # source: opens a log, picks its reader
    "vdp.io.formats": 1,  # source: one reader per log format
    "vdp.io.scan": 1,  # source: the one candump parser (both candump readers)
    "vdp.io": 2,  # decode
    "vdp.io.bulk": 3,  # decodes and aligns blocks of a candump log
    "vdp.buffer": 3,  # align
    "vdp.profilecheck": 3,  # checks a profile against a log: reads, decodes and aligns it
    "vdp.core": 4,  # supervise, learn
    "vdp.pipeline": 5,
    "vdp.replay": 5,
    "vdp.store": 6,  # what a run leaves: the store, the report, exports, fleet tables
    "vdp.report": 6,
    "vdp.series": 6,
    "vdp.export": 6,
    "vdp.fleet": 6,
    "vdp.across": 6,  # a drive's own measures and the changes across a vehicle's drives (batch, replay --after)
    "vdp.live": 7,
    "vdp.api": 8,
    "vdp.cli": 9,
    "vdp.scaffold": 1,  # drafts a profile from a DBC and a log
    "vdp.sim": 2,  # the simulator makes frames, as a source does: it may use the codec, no further
}
TOP = 9

# the simulated bus feed is part of the live service and may drive the simulator
ALLOWED = {
    ("vdp.live.simfeed", "vdp.sim"),
}

CORE_MAY_IMPORT = {"numpy", "scipy", "math", "dataclasses", "typing", "collections", "functools"}
CORE_MAY_IMPORT |= {"logging", "__future__"}
CORE_MAY_IMPORT |= {"numba"}  # core.kernels, core.prepass: the compiled steps, imported at the first filter
CORE_MAY_IMPORT |= {"hashlib", "pathlib"}  # core.jit: its cache directory, named by a hash of the compiled sources
CORE_MAY_IMPORT |= {"threading"}  # core.warm: one compile at a time
CORE_MAY_IMPORT |= {"enum"}  # core.supervisor: a reason's Code
CORE_MAY_IMPORT |= {"types"}  # core.prepass: a copy of a core.passes step that calls the compiled helpers


def module_name(path: Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def is_module(name: str) -> bool:
    parts = name.split(".")
    if parts[0] != "vdp":
        return False
    base = PKG.joinpath(*parts[1:])
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def imports(path: Path) -> set[str]:
    """Absolute names of everything ``path`` imports."""
    mod = module_name(path)
    package = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for a in node.names:  # "from pkg import mod" imports the module pkg.mod
                out.add(f"{target}.{a.name}" if is_module(f"{target}.{a.name}") else target)
    return out


def stage(name: str) -> int | None:
    """The module's stage; None for what is not vdp's.  A vdp module not listed counts as a
    top-level consumer (as the CLI): it may import anything, and nothing in the flow may import it."""
    if name == "vdp":  # the package itself (its version)
        return 0
    if not name.startswith("vdp."):
        return None
    best = None
    for prefix in STAGE:
        if (name == prefix or name.startswith(prefix + ".")) and (best is None or len(prefix) > len(best)):
            best = prefix
    return TOP if best is None else STAGE[best]


def modules() -> dict[str, set[str]]:
    return {module_name(p): imports(p) for p in sorted(PKG.rglob("*.py"))}


def test_imports_never_run_against_the_flow():
    bad = []
    for mod, deps in modules().items():
        here = stage(mod)
        for dep in deps:
            if not dep.startswith("vdp"):
                continue
            there = stage(dep)
            allowed = any(mod.startswith(a) and dep.startswith(b) for a, b in ALLOWED)
            if there > here and not allowed:
                bad.append(f"{mod} (stage {here}) imports {dep} (stage {there})")
    assert not bad, "\n".join(bad)


def test_the_core_imports_no_bus_web_storage_or_clock():
    bad = []
    for mod, deps in modules().items():
        if not mod.startswith("vdp.core"):
            continue
        for dep in deps:
            top = dep.split(".")[0]
            if top == "vdp":
                if not (dep.startswith("vdp.core") or dep in ("vdp.channels", "vdp.errors")):
                    bad.append(f"{mod} imports {dep}")
            elif top not in CORE_MAY_IMPORT:
                bad.append(f"{mod} imports {dep}")
    assert not bad, "\n".join(bad)


def _cycles(deps: dict[str, set[str]]) -> list[list[str]]:
    """The import circles among these modules (Tarjan's strongly connected components of two or more)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in deps.get(v, ()):
            if w not in deps:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(deps):
        if v not in index:
            visit(v)
    return out


def test_the_core_has_no_import_circle():
    """Within the core every import runs one way (lazy imports included): a circle is a design
    that cannot be read from the bottom up, nor a module tested without the others."""
    deps = {m: {d for d in ds if d.startswith("vdp.core")} for m, ds in modules().items() if m.startswith("vdp.core")}
    assert _cycles(deps) == []


def test_the_circle_check_sees_a_circle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_checker_sees_a_violation():
    """The checks above would fail on a real back-edge (the graph reader is not blind)."""
    deps = modules()
    assert "vdp.core.result" in deps["vdp.core.learn.base"]
    assert "vdp.io.decoder" in deps["vdp.pipeline"]
    assert stage("vdp.api.app") > stage("vdp.store") > stage("vdp.core.learner") > stage("vdp.buffer")


def test_the_pipeline_imports_neither_filterpy_nor_scipy():
    """A replay's start-up: core/filters.py writes the filter steps out, so filterpy (whose
    EKF module pulls in scipy.stats, ~0.8 s) stays the tests' reference only (BENCHMARKS.md,
    "Replay start-up").  A fresh interpreter, since this one's tests import both."""
    code = "import sys, vdp.pipeline; print(sorted(m for m in ('filterpy', 'scipy') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
