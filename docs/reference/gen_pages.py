"""The API reference: one page per module of the public packages, from their docstrings.

Run by mkdocs-gen-files at build time (``mkdocs build``): it walks ``src/aeromanip``, so a
module that moves or is added gets its page without editing the site.
"""

from pathlib import Path

import mkdocs_gen_files

SRC = Path(__file__).resolve().parents[2] / "src"
# the command line is documented by ``aeromanip --help``; private modules have no page
SKIP = {"__main__"}

nav = mkdocs_gen_files.Nav()
for path in sorted((SRC / "aeromanip").rglob("*.py")):
    module = path.relative_to(SRC).with_suffix("")
    parts = tuple(module.parts)
    if parts[-1] in SKIP or any(p.startswith("_") and p != "__init__" for p in parts):
        continue
    if parts[-1] == "__init__":
        parts = parts[:-1]
        doc = Path(*parts, "index.md")
    else:
        doc = module.with_suffix(".md")
    nav[parts] = doc.as_posix()
    with mkdocs_gen_files.open(Path("reference", doc), "w") as page:
        page.write(f"# `{'.'.join(parts)}`\n\n::: {'.'.join(parts)}\n")
    mkdocs_gen_files.set_edit_path(Path("reference", doc), path.relative_to(SRC.parent))

with mkdocs_gen_files.open("reference/SUMMARY.md", "w") as summary:
    summary.writelines(nav.build_literate_nav())
