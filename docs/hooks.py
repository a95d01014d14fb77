"""MkDocs hooks of the warp-sph documentation (mkdocs.yml: ``hooks``).

1. Repository files. A page may link to a file of the repository outside docs/ with a relative link
   (``../benchmarks/results/scaling.png``, ``../CHANGELOG.md``), which works when the page is read in
   the repository. The build copies each such file into the site at its path from the repository
   root (Markdown files become pages, and their own links are followed the same way) and rewrites
   the link to match. A link to a file that does not exist is left as it is, so the strict build
   reports it.
2. Checks, logged as warnings (so ``mkdocs build --strict`` fails): the generated scene-file
   reference is current (``python -m warp_sph.docs`` rewrites it), every public name of warp_sph
   has a docstring, and every built-in scene has its section with a picture on scenes.md.
"""
from __future__ import annotations

import logging
import os
import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.warp_sph")

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
#: repository files the nav names (mkdocs.yml), copied in even when no page links them
NAV_FILES = ("CHANGELOG.md", "benchmarks/README.md", "benchmarks/RESULTS.md")
LINK = re.compile(r"(!?\[[^\]]*\]\()([^)\s]+)((?:\s+\"[^\"]*\")?\))")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)


def _links(text: str):
    """Relative link targets of a Markdown text (not in code blocks), without their #fragment."""
    for m in LINK.finditer(FENCE.sub("", text)):
        target = m.group(2).split("#", 1)[0]
        if target and "://" not in target and not target.startswith(("/", "mailto:")):
            yield target


def _source(file: File) -> Path:
    return Path(file.abs_src_path).resolve()


def _repo_target(page_source: Path, target: str) -> Path | None:
    """The repository file outside docs/ that ``target`` (a link in ``page_source``) names, if any."""
    path = Path(os.path.normpath(page_source.parent / target))
    if path.is_file() and ROOT in path.parents and DOCS not in path.parents:
        return path
    return None


def on_files(files, config):
    todo = [_source(f) for f in files.documentation_pages()] + [ROOT / p for p in NAV_FILES]
    seen = set()
    while todo:
        source = todo.pop()
        if source in seen:
            continue
        seen.add(source)
        if DOCS not in source.parents:  # a repository file: add it at its path from the root
            rel = source.relative_to(ROOT).as_posix()
            if files.get_file_from_path(rel) is None:
                files.append(File(rel, str(ROOT), config["site_dir"], config["use_directory_urls"]))
        if source.suffix == ".md":
            text = source.read_text(encoding="utf-8")
            todo.extend(t for t in (_repo_target(source, link) for link in _links(text)) if t is not None)
    return files


def _rewrite(markdown: str, page) -> str:
    source = _source(page.file)
    here = posixpath.dirname(page.file.src_uri)

    def fix(m):
        target, _, fragment = m.group(2).partition("#")
        if not target or "://" in target:
            return m.group(0)
        path = Path(os.path.normpath(source.parent / target))
        if ROOT not in path.parents or not path.exists():
            return m.group(0)
        base = DOCS if DOCS in path.parents else ROOT
        uri = path.relative_to(base).as_posix()
        new = posixpath.relpath(uri, here or ".") + (f"#{fragment}" if fragment else "")
        return m.group(1) + new + m.group(3)

    parts = re.split(r"(^(?:```|~~~).*?^(?:```|~~~)[^\n]*$)", markdown, flags=re.S | re.M)
    return "".join(p if k % 2 else LINK.sub(fix, p) for k, p in enumerate(parts))


def on_page_markdown(markdown, page, config, files):
    return _rewrite(markdown, page)


def on_pre_build(config):
    from warp_sph import docs, list_scenes

    for page in docs.stale_pages(DOCS):
        log.warning(f"{page} is stale: run python -m warp_sph.docs")
    for name in docs.missing_docstrings():
        log.warning(f"warp_sph.{name} is public and has no docstring")
    scenes = (DOCS / "scenes.md").read_text(encoding="utf-8")
    for name, _ in list_scenes():
        section = re.search(rf"^## {re.escape(name)}\n(.*?)(?=^## |\Z)", scenes, re.S | re.M)
        if section is None or "![" not in section.group(1):
            log.warning(f"docs/scenes.md: the built-in scene {name!r} has no section '## {name}' with a picture")
