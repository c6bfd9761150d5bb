"""The C header templates (Jinja2) of ``ns2 export``: package ``ns2codegen.templates``,
mapped to this top-level folder by pyproject.toml's package-dir, so a wheel carries
them as package data of the core (ns2codegen/export.py finds them)."""
