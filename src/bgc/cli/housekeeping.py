"""The `bgc` commands that look after files: examples (copy the example models) and cache (the
compile cache's info and clear). Click commands that bgc.cli.commands adds to the `bgc`
group."""
from __future__ import annotations

import click

from bgc.base.errors import ModelError
from bgc.base.paths import package_dir


@click.command("examples")
@click.argument("directory", type=click.Path(file_okay=False))
def examples_cmd(directory):
    """Copy the example models and scenes (and the format reference) into DIRECTORY; nothing
    that already exists there is overwritten (then nothing is copied)."""
    import os

    # lazy: the compile path, which a warm run never loads
    from bgc.base.outdirs import check_in, copy_file, out_folder

    files = _example_files()
    dest = out_folder(directory, "examples", create=False)
    for rel in files:  # a link on the way or at a file's place: refused before any copy
        check_in(dest, rel, None, "examples")
    clash = [rel for rel in files if os.path.lexists(dest / rel)]
    if clash:
        raise ModelError(None, f"{dest}: {len(clash)} file(s) exist already (e.g. {clash[0]}); "
                               "nothing copied: choose an empty or new directory")
    dest = out_folder(directory, "examples")
    for rel, src in files.items():
        copy_file(src, dest, rel, None, "examples")
    click.echo(f"copied {len(files)} files to {dest} (try: bgc simulate "
               f"{dest / 'models' / 'scenes' / 'msd_step.yaml'} --plot figs/)")


def _example_files() -> dict:
    """relative path -> source file: the repository's models/ and docs/model-format.md in a
    source checkout, else the installed copies (bgc.examples, bgc.docs)."""
    here = package_dir()  # src/bgc in a checkout, site-packages/bgc when installed
    root = here.parent.parent
    if (root / "models" / "msd.yaml").is_file():
        models, docs = root / "models", root / "docs"
    else:  # installed wheel: bgc/examples and bgc/docs beside the package's modules
        models, docs = here / "examples", here / "docs"
    out = {}
    for f in sorted(models.glob("*.yaml")):
        out[f"models/{f.name}"] = f
    for f in sorted((models / "scenes").glob("*")):
        if f.suffix in (".yaml", ".csv"):
            out[f"models/scenes/{f.name}"] = f
    for name in ("model-format.md", "api.md", "library.md"):
        if (docs / name).is_file():
            out[f"docs/{name}"] = docs / name
    return out


@click.group("cache")
def cache_cmd():
    """The compile cache ($BGC_CACHE_DIR, else ~/.cache/bgc)."""


@cache_cmd.command("info")
def cache_info_cmd():
    """Where the cache is, how many entries per target, how many bytes."""
    # lazy: the cache's module (and the C compiler's identity) for this command only
    from bgc.run.cache import Cache

    info = Cache().info()
    ents = ", ".join(f"{k} {v}" for k, v in info["entries"].items()) or "empty"
    click.echo(f"{info['path']}: {ents}; {info['bytes'] / 1e6:.1f} MB")


@cache_cmd.command("clear")
def cache_clear_cmd():
    """Remove every cache entry."""
    # lazy: the cache's module (and the C compiler's identity) for this command only
    from bgc.run.cache import Cache

    c = Cache()
    n = c.clear()
    click.echo(f"{c.path}: removed {n} entries")
    if c.kept:  # a folder the cache was pointed at: bgc removes only what it made
        shown = ", ".join(str(p) for p in c.kept[:3]) + (", ..." if len(c.kept) > 3 else "")
        click.echo(f"note: left {len(c.kept)} item(s) bgc did not make: {shown}", err=True)
