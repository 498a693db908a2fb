"""The picture of the house: the stage packages and which imports which, read from the code.

``python -m reports.house`` writes ``docs/house.md`` (a Mermaid graph, the
package table, the import circles and the imports left inside functions) and
``docs/images/house.png``. The arrows are not drawn by hand: every import
statement of every module is read (also the ones inside functions), so the
picture changes when the code does, and ``tests/test_layers.py`` checks that
the committed page matches the code, that no arrow points down a floor, that
no modules import each other in a circle and how many imports are deferred.
"""

from __future__ import annotations

import ast
import io
import logging
from dataclasses import dataclass
from pathlib import Path

import matplotlib

ROOT = Path(__file__).resolve().parents[1]

# The stages, bottom to top, with what each holds (the README's code map).
STAGES: tuple[tuple[str, str], ...] = (
    ("storage", "local and S3 roots via pyarrow.fs, atomic writes, checksums, bytes for pyarrow"),
    ("domains", "the domain vocabulary: classes, the catalog of towns, weathers and viewpoints (rows, the TOML "
                "file), the selection grammar, per-frame conditions, weather ramps, fog"),
    ("outputs", "the output table and its encoders: PNG deflaters, the objects sidecar, camera geometry"),
    ("manifests", "the Parquet manifest: schema and the root's rules, file layout, part files, writer, reader, "
                  "summaries, query, stats, synthetic rows"),
    ("roots", "the root's contract: what marks a root, leases, the run record (run.json; its config's shape "
              "handed in), the job spec and what the renderer takes of it (DrawSpec), verify"),
    ("render_workers.worlds", "towns as data and meshes: town plan, feature modules on a shared builder, "
                              "textures, styles, traffic, world cache; no GL"),
    ("render_workers.render", "pyrender off-screen: its set-up and patches, shaders, part meshes, camera, sky, "
                              "post effects, instances; an episode gives named buffers"),
    ("exports", "one module per output format over what they share; the dataset card"),
    ("analysis", "loaders, metrics, the small segmentation net, distances, the domain-shift table, real "
                 "folders, evaluate (torch extra)"),
    ("pipeline", "planner, a run's settings (one module; run.json's config tables read from its fields), "
                 "provenance, the Ray distributor and cluster attach, the episode job (buffers -> files -> manifest "
                 "part), repair, verify on Ray"),
    ("pipeline.cli", "the Typer app and its shared options"),
    ("reports", "make report's generators (docs/worlds.md, this page)"),
)
NAMES = tuple(name for name, _ in STAGES)
# Where modules are read for the circles and the deferred imports (benchmarks too; not tests).
SOURCES = ("storage", "domains", "outputs", "manifests", "roots", "render_workers", "exports", "analysis", "pipeline",
           "reports", "benchmarks")

log = logging.getLogger(__name__)


def stage_of(module: str) -> str | None:
    """The stage a dotted module name belongs to (the longest stage prefix)."""
    best = None
    for name in NAMES:
        if module == name or module.startswith(name + "."):
            best = name if best is None or len(name) > len(best) else best
    return best


@dataclass(frozen=True)
class Import:
    importer: str  # dotted module name
    imported: str  # one of our modules (or packages)
    line: int
    deferred: bool  # inside a function (not run when the module is imported)


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Every module of ours by dotted name (a package by its own name)."""
    out = {}
    for top in SOURCES:
        for path in sorted((root / top).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _top_level(tree: ast.Module) -> set[int]:
    """ids of the statements that run when the module is imported (module level, also under if/try)."""
    seen, todo = set(), list(tree.body)
    while todo:
        node = todo.pop()
        seen.add(id(node))
        if isinstance(node, (ast.If, ast.Try, ast.With)):
            for field in ("body", "orelse", "finalbody"):
                todo += getattr(node, field, [])
            todo += [s for h in getattr(node, "handlers", []) for s in h.body]
    return seen


def imports(root: Path = ROOT) -> list[Import]:
    """Every import of one of our modules by one of them. ``from pkg import mod`` is an import of
    ``pkg.mod``; ``from mod import name`` one of ``mod``."""
    known = modules(root)

    def ours(name: str) -> str | None:
        while name and name not in known:
            name = name.rpartition(".")[0]
        return name or None

    out = []
    for importer, path in known.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        top = _top_level(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = {ours(a.name) for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                subs = [f"{node.module}.{a.name}" for a in node.names]
                targets = {s for s in subs if s in known}
                if len(targets) < len(subs):
                    targets.add(ours(node.module))
            else:
                continue
            for target in sorted(t for t in targets if t and t != importer):
                out.append(Import(importer, target, node.lineno, id(node) not in top))
    return out


def deferred(found: list[Import] | None = None, benchmarks: bool = False) -> list[Import]:
    """The imports of our modules written inside functions, in the packages (with ``benchmarks``: in
    ``benchmarks/``, whose probes run inside the measured revision's tree and import it there)."""
    found = imports() if found is None else found
    late = {(i.importer, i.line): i for i in found if i.deferred and (i.importer.split(".")[0] == "benchmarks") == benchmarks}
    return sorted(late.values(), key=lambda i: (i.importer, i.line))


def circles(found: list[Import] | None = None) -> list[list[str]]:
    """Groups of modules that import each other, directly or round a loop (deferred imports included)."""
    found = imports() if found is None else found
    graph: dict[str, set[str]] = {}
    for i in found:
        graph.setdefault(i.importer, set()).add(i.imported)
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def edges(root: Path = ROOT) -> set[tuple[str, str]]:
    """(importer, imported) stage pairs over every module of every stage."""
    out = set()
    for i in imports(root):
        a, b = stage_of(i.importer), stage_of(i.imported)
        if a and b and a != b:
            out.add((a, b))
    return out


def _node(name: str) -> str:
    return name.replace(".", "_")


def mermaid(pairs: set[tuple[str, str]]) -> str:
    lines = ["```mermaid", "graph BT"]
    lines += [f'    {_node(n)}["{n}/"]'.replace(".", "/", 1) if "." in n else f'    {_node(n)}["{n}/"]' for n in NAMES]
    lines += [f"    {_node(a)} --> {_node(b)}" for a, b in sorted(pairs)]
    lines.append("```")
    return "\n".join(lines)


def markdown(pairs: set[tuple[str, str]], found: list[Import] | None = None) -> str:
    found = imports() if found is None else found
    rows = "\n".join(f"| `{n.replace('.', '/')}/` | {what} |" for n, what in STAGES)
    loops = circles(found)
    late = deferred(found)
    bench = deferred(found, benchmarks=True)
    late_rows = "\n".join(f"| `{i.importer}` | `{i.imported}` |" for i in late)
    return f"""# The house: one package per stage

Each stage of the pipeline is one package; an arrow goes from a package to one it imports. The graph is read
from the code by `python -m reports.house` (every import statement, also the ones inside functions), and
`tests/test_layers.py` checks that this page matches the code and that no arrow points down the wrong way.

![the house](images/house.png)

{mermaid(pairs)}

| package | what is inside |
|---|---|
{rows}

The floors, bottom to top: `storage` <- `domains` <- `outputs` <- `manifests` <- `roots` <- `render_workers`
(`worlds` <- `render`) <- `exports`, `analysis` <- `pipeline` (`cli`) <- `reports`. A package imports only
from the floors below it. Rules the layer test enforces besides: `render_workers` imports no Ray, its `worlds/`
no GL, nothing of `render/` and of ours only `domains` (the world cache's digest covers what they read); only
`pipeline` and the consumer layer `analysis` (and `reports`) import Ray.

Import circles between modules, imports inside functions included: {len(loops) or "none"}.

Imports of our modules written inside functions, in the packages: {len(late)} (the layer test allows fewer
than 40). The rest are at the top of their modules. Those left keep optional heavy dependencies off the
paths that do not need them (the renderer for the CLI commands that render; torch behind the analysis
commands, the report sections and the segmentation net), keep the Ray worker's module light for the progress
actor, or are guarded by a `try` or an `if` (a local cluster's reaper, an S3 outage's message). The
benchmarks hold {len(bench)} more: a benchmark's probe runs inside the measured revision's tree (the
"before" side) and imports that tree's modules there, under their names of that revision.

| module | imports, inside a function |
|---|---|
{late_rows}
"""


def reduced(pairs: set[tuple[str, str]]) -> set[tuple[str, str]]:
    """The arrows not implied by a longer path (the transitive reduction), for a readable picture."""
    def reach(start: str, skip: tuple[str, str]) -> set[str]:
        seen, todo = set(), [start]
        while todo:
            node = todo.pop()
            for a, b in pairs:
                if a == node and (a, b) != skip and b not in seen:
                    seen.add(b)
                    todo.append(b)
        return seen

    return {(a, b) for a, b in pairs if b not in reach(a, (a, b))}


def png(pairs: set[tuple[str, str]]) -> bytes:
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # bottom-to-top rows; stages on one row sit side by side
    rows = [["storage"], ["domains"], ["outputs"], ["manifests"], ["roots"], ["render_workers.worlds"],
            ["render_workers.render"], ["exports", "analysis"], ["pipeline"], ["pipeline.cli", "reports"]]
    pos = {}
    for y, row in enumerate(rows):
        for i, name in enumerate(row):
            pos[name] = ((i + 1) / (len(row) + 1), y)
    fig, ax = plt.subplots(figsize=(7.5, 8.5), dpi=110)
    for a, b in sorted(reduced(pairs)):
        (x0, y0), (x1, y1) = pos[a], pos[b]
        ax.annotate("", xy=(x1, y1 + 0.22), xytext=(x0, y0 - 0.22),
                    arrowprops=dict(arrowstyle="->", color="#7a7a7a", lw=0.9, shrinkA=2, shrinkB=2,
                                    connectionstyle="arc3,rad=0.12"))
    for name, (x, y) in pos.items():
        ax.text(x, y, name.replace(".", "/") + "/", ha="center", va="center", fontsize=10, family="monospace",
                bbox=dict(boxstyle="round,pad=0.45", fc="#eef3fb", ec="#3a5a8c"))
    ax.set_xlim(0, 1)
    ax.set_ylim(-0.6, len(rows) - 0.4)
    ax.axis("off")
    ax.set_title("Packages and their imports (an arrow: imports; arrows implied by a path left out)", fontsize=10)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def main(docs: str = "docs") -> None:
    pairs = edges()
    out = Path(docs)
    (out / "images").mkdir(parents=True, exist_ok=True)
    (out / "house.md").write_text(markdown(pairs, imports()))
    (out / "images" / "house.png").write_bytes(png(pairs))
    log.info("wrote %s and %s (%d arrows)", out / "house.md", out / "images" / "house.png", len(pairs))


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main()
