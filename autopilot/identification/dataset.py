"""Input-output data for identification: the CSV file format and its validation.

Format: a CSV file (comma separated, "." decimal point) with one header row naming the
columns, then one row per sample. Units SI, frames NED / FRD (docs/conventions.md):

    time_s                                   sample time [s], strictly increasing
    phi_rad, theta_rad, psi_rad              Euler angles [rad]
    phi_rate_rad_s, theta_rate_rad_s, psi_rate_rad_s   Euler angle rates [rad/s]
    w_r_rad_s                                residual rotor speed sum s_i W_i [rad/s]
                                             (W1 - W2 + W3 - W4 on the paper's "+")
    u_phi_n, u_theta_n                       roll / pitch torques as forces at the
                                             reference arms, U_phi, U_theta [N]
    u_psi_nm                                 yaw torque U_psi [N m]
    phi_acc_rad_s2, theta_acc_rad_s2, psi_acc_rad_s2   angular accelerations [rad/s^2]
    f_phi, f_theta, f_psi                    optional: the unknown functions f_i(x)
                                             [rad/s^2], when a simulator hands them over

Columns may come in any order; every required column must be there and no other. Every
value must be a finite number. A file that breaks any rule raises DatasetError naming
the file, line and column, and no Dataset is built from it.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from autopilot.models.regressors import current_column_name
from contracts.atomic_file import atomic_writer
from contracts.vectors import ATTITUDE_CHANNELS

REQUIRED_COLUMNS: tuple[str, ...] = (
    "time_s",
    "phi_rad",
    "theta_rad",
    "psi_rad",
    "phi_rate_rad_s",
    "theta_rate_rad_s",
    "psi_rate_rad_s",
    "w_r_rad_s",
    "u_phi_n",
    "u_theta_n",
    "u_psi_nm",
    "phi_acc_rad_s2",
    "theta_acc_rad_s2",
    "psi_acc_rad_s2",
)
OPTIONAL_COLUMNS: tuple[str, ...] = ("f_phi", "f_theta", "f_psi")
ALL_COLUMNS: tuple[str, ...] = REQUIRED_COLUMNS + OPTIONAL_COLUMNS

CHANNELS: tuple[str, ...] = ATTITUDE_CHANNELS
CHANNEL_INPUT: dict[str, str] = {"phi": "u_phi_n", "theta": "u_theta_n", "psi": "u_psi_nm"}
CHANNEL_ACCELERATION: dict[str, str] = {
    "phi": "phi_acc_rad_s2",
    "theta": "theta_acc_rad_s2",
    "psi": "psi_acc_rad_s2",
}
CHANNEL_FUNCTION: dict[str, str] = {"phi": "f_phi", "theta": "f_theta", "psi": "f_psi"}

MIN_ROWS = 10  # fewer samples cannot describe any excitation flight


class DatasetError(ValueError):
    """A dataset file or Dataset that breaks the format; the message says where."""


def _first_bad_row(values: np.ndarray) -> int | None:
    bad = np.flatnonzero(~np.isfinite(values))
    return int(bad[0]) if bad.size else None


def _check_columns(columns: dict[str, np.ndarray], where: str) -> dict[str, np.ndarray]:
    """Validate a column mapping; returns float64 copies in canonical order.

    Data row k (0-based) is line k + 2 of a file (line 1 is the header).
    """
    unknown = [name for name in columns if name not in ALL_COLUMNS]
    if unknown:
        raise DatasetError(f"{where}: unknown column {unknown[0]!r}")
    missing = [name for name in REQUIRED_COLUMNS if name not in columns]
    if missing:
        raise DatasetError(f"{where}: missing required column {missing[0]!r}")
    out: dict[str, np.ndarray] = {}
    n_rows = None
    for name in ALL_COLUMNS:
        if name not in columns:
            continue
        try:
            values = np.array(columns[name], dtype=float)
        except (TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: column {name!r} is not numeric ({exc})") from None
        if values.ndim != 1:
            raise DatasetError(f"{where}: column {name!r} must be 1-D, got {values.ndim}-D")
        if n_rows is None:
            n_rows = values.shape[0]
        elif values.shape[0] != n_rows:
            raise DatasetError(
                f"{where}: column {name!r} has {values.shape[0]} rows, expected {n_rows}"
            )
        bad = _first_bad_row(values)
        if bad is not None:
            raise DatasetError(
                f"{where}: line {bad + 2} (data row {bad + 1}), column {name!r}: "
                f"value {values[bad]} is not finite"
            )
        out[name] = values
    assert n_rows is not None
    if n_rows < MIN_ROWS:
        raise DatasetError(f"{where}: too few rows: {n_rows} (at least {MIN_ROWS})")
    step = np.diff(out["time_s"])
    bad_steps = np.flatnonzero(step <= 0.0)
    if bad_steps.size:
        k = int(bad_steps[0]) + 1
        raise DatasetError(
            f"{where}: line {k + 2} (data row {k + 1}), column 'time_s': time "
            f"{out['time_s'][k]!r} does not increase (previous {out['time_s'][k - 1]!r})"
        )
    return out


@dataclass(frozen=True, eq=False)
class Dataset:
    """Validated input-output samples, one float64 array per column.

    Building one validates it, so every Dataset in the program is well formed.
    """

    columns: dict[str, np.ndarray]
    source: str = field(default="<memory>")

    def __post_init__(self) -> None:
        object.__setattr__(self, "columns", _check_columns(dict(self.columns), self.source))

    @property
    def n_rows(self) -> int:
        return int(self.columns["time_s"].shape[0])

    def has(self, name: str) -> bool:
        return name in self.columns

    def column(self, name: str) -> np.ndarray:
        """One column; KeyError names it when absent."""
        if name not in self.columns:
            raise KeyError(f"dataset {self.source} has no column {name!r}")
        return self.columns[name]

    def matrix(self, names: tuple[str, ...] | list[str]) -> np.ndarray:
        """Columns stacked side by side, (N, len(names))."""
        return np.column_stack([self.column(name) for name in names])


def read_dataset(path: str | os.PathLike[str]) -> Dataset:
    """Read and validate a dataset CSV file; DatasetError names file, line and column."""
    where = str(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:  # tolerate a BOM
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise DatasetError(f"{where}: cannot read file ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DatasetError(f"{where}: not a text CSV file ({exc})") from None
    if not rows:
        raise DatasetError(f"{where}: empty file, expected a header row")
    header = [current_column_name(name.strip()) for name in rows[0]]
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise DatasetError(f"{where}: line 1: duplicate column {name!r}")
        seen.add(name)
    for name in header:
        if name not in ALL_COLUMNS:
            raise DatasetError(f"{where}: line 1: unknown column {name!r}")
    for name in REQUIRED_COLUMNS:
        if name not in seen:
            raise DatasetError(f"{where}: line 1: missing required column {name!r}")

    data = np.empty((len(rows) - 1, len(header)))
    for k, row in enumerate(rows[1:]):
        line = k + 2
        if len(row) != len(header):
            raise DatasetError(f"{where}: line {line}: {len(row)} fields, header has {len(header)}")
        for j, text in enumerate(row):
            try:
                value = float(text)
            except ValueError:
                raise DatasetError(
                    f"{where}: line {line}, column {header[j]!r}: {text!r} is not a number"
                ) from None
            if not math.isfinite(value):
                raise DatasetError(
                    f"{where}: line {line}, column {header[j]!r}: {text!r} is not finite"
                )
            data[k, j] = value
    return Dataset(columns={name: data[:, j] for j, name in enumerate(header)}, source=where)


def _format(value: float) -> str:
    return repr(float(value))  # shortest text that reads back bit for bit


def write_dataset(path: str | os.PathLike[str], dataset: Dataset) -> None:
    """Write a dataset CSV (canonical column order, exact round trip).

    Written to a temporary file beside the target and renamed over it, so a failure
    never leaves a half-written file.
    """
    columns = _check_columns(dict(dataset.columns), str(path))
    names = [name for name in ALL_COLUMNS if name in columns]
    with atomic_writer(Path(path), text=True) as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(names)
        table = np.column_stack([columns[name] for name in names])
        for row in table:
            writer.writerow([_format(v) for v in row])
