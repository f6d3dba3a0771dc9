"""Reading a configuration that is either shipped (by name) or the user's TOML file (by
path): airframes (contracts/airframes) and sensor profiles (sitl/sensor_profiles)."""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any


def shipped_names(package: str, folder: str) -> list[str]:
    return sorted(p.name[:-5] for p in resources.files(package).joinpath(folder).iterdir()
                  if p.name.endswith(".toml"))


def read_named_toml(source: str | Path, package: str, folder: str, what: str,
                    error: type[ValueError]) -> tuple[dict[str, Any], str]:
    """(the table, where it came from for messages) of a shipped name or a .toml path;
    ``error`` (naming ``what``) for an unknown name, a missing file or bad TOML."""
    text = str(source)
    if text in shipped_names(package, folder):
        path = resources.files(package).joinpath(folder, f"{text}.toml")
        where = f"{what} {text}"
    elif text.endswith(".toml") or "/" in text:
        path, where = Path(text), f"{what} file {text}"
    else:
        raise error(f"unknown {what} {text!r}; shipped: "
                    f"{', '.join(shipped_names(package, folder))} (or a .toml file)")
    try:
        return tomllib.loads(path.read_text()), where
    except FileNotFoundError:
        raise error(f"{where}: no such file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{where}: not TOML: {exc}") from None
