"""Developer tool: regenerate bakery's USD schema plugin from ``schemas/usd/schema.usda``.

Run from the repository root after editing the schema::

    python -m bakery.usd.sync_schemas      # needs jinja2: pip install -e ".[schema]"

It writes ``generatedSchema.usda`` and ``plugInfo.json`` to ``schemas/usd/`` and to ``bakery/usd/schema/`` (package
data); see :func:`bakery.usd.plugin.sync_schemas`.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

from bakery.usd.plugin import PLUGIN_DIR, sync_schemas


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    source = Path(args[0]) if args else Path("schemas/usd")
    if not (source / "schema.usda").is_file():
        print(f"{source / 'schema.usda'} not found; run from the repository root or pass the schema directory")
        return 2
    if importlib.util.find_spec("jinja2") is None:
        print('usdGenSchema needs jinja2: pip install -e ".[schema]"')
        return 2
    sync_schemas(source)
    print(f"regenerated {source} and {PLUGIN_DIR}")
    return 0


if __name__ == "__main__":  # pragma: no cover - developer tool
    sys.exit(main())
