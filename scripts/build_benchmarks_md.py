"""Rebuild docs/BENCHMARKS.md: its header and targets table, then every docs/bench/*.md page.

    python scripts/build_benchmarks_md.py

The header (everything before the first ``---`` line) is kept as written; each page follows
with its headings one level down (outside code fences), then the sweep's curves.
"""

from __future__ import annotations

from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"
PAGES = (
    "sim",
    "paper",
    "optim",
    "redq",
    "tables",
    "service",
    "load",
    "workers",
    "sim_to_real",
    "dashboard",
)


def demote(text: str) -> str:
    out, fenced = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        out.append("#" + line if not fenced and line.startswith("#") else line)
    return "\n".join(out).strip() + "\n"


def main() -> None:
    target = DOCS / "BENCHMARKS.md"
    header = target.read_text().split("\n---\n", 1)[0].rstrip() + "\n"
    parts = [header]
    for name in PAGES:
        parts.append(demote((DOCS / "bench" / f"{name}.md").read_text()))
    parts.append(
        "## Best-so-far curves of the optimiser sweep\n\n"
        "![best-so-far curves, P = 2 and 5, both tasks (seeds per method in the legend)]"
        "(bench/optim/curves.png)\n"
    )
    target.write_text("\n---\n\n".join(parts))


if __name__ == "__main__":
    main()
