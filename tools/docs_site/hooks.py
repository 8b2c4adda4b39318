"""MkDocs hooks (`mkdocs.yml` `hooks:`): the generated pages join the hand-written ones of docs/.

The pages themselves are written by `reference_pages`; here they are only handed over, replacing any
file of the same name in docs/ (docs/protocol.md and docs/protocol_pq.md, kept for readers of the
repository, are rendered anew so the site never shows a stale copy).
"""

from __future__ import annotations

from typing import Any

from mkdocs.structure.files import File, Files
from reference_pages import generated_pages, navigation


def on_config(config: Any) -> Any:
    config.nav = navigation()
    return config


def on_files(files: Files, config: Any) -> Files:
    for path, text in generated_pages().items():
        existing = files.get_file_from_path(path)
        if existing is not None:
            files.remove(existing)
        files.append(File.generated(config, path, content=text))
    return files
