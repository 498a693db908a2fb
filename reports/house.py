"""The picture of the house: the stage packages and which imports which, read from the code.

``python -m reports.house`` writes ``docs/house.md`` (a Mermaid graph and the
package table) and ``docs/images/house.png``. The arrows are not drawn by hand:
every import statement of every module is read (as ``tests/test_layers.py``
does), so the picture changes when the code does, and a test checks that the
committed page matches the code.
"""

from __future__ import annotations

import ast
import logging
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# The stages, bottom to top, with what each holds (the README's code map).
STAGES: tuple[tuple[str, str], ...] = (
    ("storage", "local and S3 roots via pyarrow.fs, atomic writes, checksums"),
    ("manifests", "the dataset contract: classes, catalog of domains, outputs and encoders, schema, writer, reader, "
                  "verify, query, stats"),
    ("render_workers.worlds", "towns as data and meshes: town plan, feature modules, kit, textures, styles, traffic, "
                              "world cache; no GL"),
    ("render_workers.render", "pyrender off-screen: renderer and its patches, shaders, camera, sky, post effects, "
                              "instances; an episode gives named buffers"),
    ("exports", "one module per output format over shared frame placing; the dataset card"),
    ("analysis", "loaders, metrics, the small segmentation net, distances, shifts, evaluate (torch extra)"),
    ("pipeline", "planner, run metadata, the Ray distributor and cluster attach, the episode job (buffers -> files -> manifest part), repair, verify on Ray"),
    ("pipeline.cli", "the Typer app and its shared options"),
    ("reports", "make report's generators (docs/worlds.md, this page)"),
)
NAMES = tuple(name for name, _ in STAGES)

log = logging.getLogger(__name__)


def stage_of(module: str) -> str | None:
    """The stage a dotted module name belongs to (the longest stage prefix)."""
    best = None
    for name in NAMES:
        if module == name or module.startswith(name + "."):
            best = name if best is None or len(name) > len(best) else best
    return best


def _imported(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return found


def edges(root: Path = ROOT) -> set[tuple[str, str]]:
    """(importer, imported) stage pairs over every module of every stage."""
    out = set()
    for name in NAMES:
        for path in sorted((root / name.replace(".", "/")).glob("*.py")):
            for module in _imported(path):
                target = stage_of(module)
                if target and target != name and stage_of(target) == target:
                    out.add((name, target))
    return out


def _node(name: str) -> str:
    return name.replace(".", "_")


def mermaid(pairs: set[tuple[str, str]]) -> str:
    lines = ["```mermaid", "graph BT"]
    lines += [f'    {_node(n)}["{n}/"]'.replace(".", "/", 1) if "." in n else f'    {_node(n)}["{n}/"]' for n in NAMES]
    lines += [f"    {_node(a)} --> {_node(b)}" for a, b in sorted(pairs)]
    lines.append("```")
    return "\n".join(lines)


def markdown(pairs: set[tuple[str, str]]) -> str:
    rows = "\n".join(f"| `{n.replace('.', '/')}/` | {what} |" for n, what in STAGES)
    return f"""# The house: one package per stage

Each stage of the pipeline is one package; an arrow goes from a package to one it imports. The graph is read
from the code by `python -m reports.house` (every import statement, also the ones inside functions), and
`tests/test_layers.py` checks that this page matches the code and that no arrow points down the wrong way.

![the house](images/house.png)

{mermaid(pairs)}

| package | what is inside |
|---|---|
{rows}

Rules the layer test enforces: `storage` imports nothing of ours; `manifests` only `storage`; `render_workers`
no Ray, and its `worlds/` no GL and nothing of `render/`; only `pipeline` and the consumer layer `analysis` (and
`reports`) import Ray.
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
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # bottom-to-top rows; stages on one row sit side by side
    rows = [["storage"], ["manifests"], ["render_workers.worlds"], ["render_workers.render"], ["exports", "analysis"],
            ["pipeline"], ["pipeline.cli", "reports"]]
    pos = {}
    for y, row in enumerate(rows):
        for i, name in enumerate(row):
            pos[name] = ((i + 1) / (len(row) + 1), y)
    fig, ax = plt.subplots(figsize=(7.5, 6.5), dpi=110)
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
    (out / "house.md").write_text(markdown(pairs))
    (out / "images" / "house.png").write_bytes(png(pairs))
    log.info("wrote %s and %s (%d arrows)", out / "house.md", out / "images" / "house.png", len(pairs))


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main()
