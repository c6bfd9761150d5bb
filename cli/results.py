"""`ns2 results`: README's results table and the docs' tables rewritten from the committed
result files (docs/results/runs/; ns2exp.tables, docs/experiments.md)."""
from __future__ import annotations

from pathlib import Path

import click

from .common import main


@main.command("results")
@click.option("--root", type=click.Path(file_okay=False), default=".", show_default=True,
              help="the checkout (README.md, docs/, docs/results/runs/)")
@click.option("--check", is_flag=True, help="write nothing: exit 1 if a generated block differs from what it would write")
@click.option("--collect", "collect", multiple=True,
              help="first copy this experiment's stamped result files from build/ into docs/results/runs/ (repeat)")
def results(root, check, collect):
    """Rewrite every generated table (between <!-- results:begin --> / <!-- results:end -->
    and <!-- results:NAME:begin --> / <!-- results:NAME:end -->) from the committed result files."""
    from ns2exp.tables import collect as collect_files
    from ns2exp.tables import write

    if check and collect:
        raise click.UsageError("--check writes nothing: not with --collect")
    for key in collect:
        got = collect_files(Path(root), key)
        click.echo(f"{key}: " + (", ".join(got) if got else "no result file in build/ to collect"))
    changed = write(Path(root), check=check)
    if check and changed:
        raise click.ClickException("generated tables out of date (run `make results`): " + ", ".join(changed))
    click.echo(("up to date: " if check or not changed else "rewrote ") + (", ".join(changed) or "README.md, docs"))
