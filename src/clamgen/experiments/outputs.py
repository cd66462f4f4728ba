"""Output file stems of the commands that write results (`clamgen eval`, `clamgen render`)."""

from __future__ import annotations

from pathlib import Path


def check_output_stem(stem: Path, suffixes: tuple[str, ...], overwrite: bool) -> Path:
    """`stem`, from which a command writes `stem` + each of `suffixes` (`.json`, `.md`, ...).

    A ValueError when its name ends in another suffix, which the files' suffixes would
    replace (`--out run-0.1` would write `run-0.json`); a FileExistsError when one of the
    files exists and `overwrite` is False.
    """
    if stem.suffix and stem.suffix not in suffixes:
        raise ValueError(
            f"output {stem}: its {stem.suffix!r} would be read as a file suffix and replaced; "
            f"pass --out with a name without that dot (e.g. {stem.name.replace('.', 'p')})"
        )
    existing = [stem.with_suffix(s) for s in suffixes if stem.with_suffix(s).exists()]
    if existing and not overwrite:
        raise FileExistsError(
            f"{existing[0]} exists; pass --overwrite to replace it, or --out to write elsewhere"
        )
    return stem
