"""`bgc library [NAME]`: the component library that ships with bgc (bgc/format/library), as
its own files describe it (bgc.format.catalogue): every library and its components, one
library's components in full, or one component."""
from __future__ import annotations

import click

from bgc.base.errors import ModelError


@click.command("library")
@click.argument("name", required=False)
def library_cmd(name):
    """List the component library (a model imports one with `imports: [{from:
    "bgc:NAME"}]`), or show one library (e.g. mechanics.spatial) or one component (e.g.
    rigid_rod) in full: its ports and their domains, its parameters with units and defaults,
    its states and laws."""
    # lazy: the library's files are read for this command only, not for `bgc --help`
    from bgc.format.catalogue import catalogue, describe, find, library_text
    from bgc.format.library import PREFIX

    if name is None:
        click.echo(catalogue() + f"\nbgc library NAME shows one library or component in full; "
                                 f"a model imports a library with imports: [{{from: "
                                 f"\"{PREFIX}NAME\"}}]")
        return
    found = find(name.removeprefix(PREFIX))
    if found is None:
        shown = name if len(name) <= 80 else name[:77] + "..."
        raise ModelError(None, f"the library has no library or component named {shown!r} "
                               "(bgc library lists them)")
    lib, comp = found
    click.echo((describe(comp, lib) if comp is not None else library_text(lib)).rstrip())
