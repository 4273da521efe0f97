"""Schemas: the single source of truth for channels, units, test kinds and warehouse DDL."""
from importlib import resources


def ddl_statements() -> list[tuple[str, str]]:
    """Every warehouse DDL file as ``(file name, SQL)``, in load order (file name order)."""
    files = sorted((f for f in resources.files("schemas.ddl").iterdir() if f.name.endswith(".sql")),
                   key=lambda f: f.name)
    return [(f.name, f.read_text(encoding="utf-8")) for f in files]
