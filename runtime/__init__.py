"""softplc runtime: language, compiler, engine, plant, scheduler, console, CLI."""


def package_version() -> str:
    """The installed package's version (importlib.metadata), or a word saying it is not
    installed (run from a source tree without ``pip install``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("softplc")
    except PackageNotFoundError:
        return "(not installed: run from a source tree)"
