"""One reader for every TOML file of the project: calibration, arm, camera, scenes, twin and bench.

Each file is read with :func:`read_toml` and taken apart table by table with a :class:`TableReader`:
typed values come out through converters (``number``, ``integer``, ``vector``, ``boolean``, ``text``,
``choice``), nested tables through ``sub``, arrays of tables through ``tables``, and ``done``
refuses the keys nobody took (a misspelt key is an error, with the closest known key). Every
error is a :class:`ConfigFileError` (or a subclass a loader names) that starts with the file and
names the key, in one wording for every file::

    models/twin.toml: key [render] seed: expected an integer in [0, 9223372036854775807], got -1
    models/twin.toml: missing key [physics] timestep_s
    models/twin.toml: unknown key [render] sed; did you mean 'seed'? (known keys: seed, tube_sides)

A file made of arrays of tables (``[[section]]`` with ``[[section.pma]]`` inside) names its keys
by their dotted path instead (``key 'section[1].pma[0].kind'``: ``dotted=True``).

    reader = TableReader(path, read_toml(path, "camera"))
    image = reader.sub("image")
    width = image.take("width_px", integer(16, 16384))
    image.done()

It lives in the estimator, the lowest layer with a file to read (the calibration), so every layer
above uses the same one.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

_MISSING: Any = ...


class ConfigFileError(ValueError):
    """A configuration file is missing, not TOML, or has an unknown, missing or bad key; names file and key."""


def _described(what: str) -> str:
    return f"{what} file" if what else "file"


def read_toml(path: str | Path, what: str = "", error: type[ConfigFileError] = ConfigFileError) -> dict[str, Any]:
    """The parsed TOML file ``path``.

    Args:
        path: the file.
        what: what kind of file it is, for messages ("calibration", "camera", ...; "" just "file").
        error: the error class to raise (a subclass of ConfigFileError a loader documents).

    Raises:
        ConfigFileError (``error``): the file is missing, unreadable or not TOML; the message starts with it.
    """
    path = Path(path)
    described = _described(what)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as e:
        raise error(f"{path}: {described} not found") from e
    except (OSError, UnicodeDecodeError) as e:
        raise error(f"{path}: cannot read the {described} ({e})") from e
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{path}: not a TOML {described}: not valid TOML ({e})") from e


class TableReader:
    """Take typed values out of one TOML table; every error names the file and the key.

    Args:
        path: the file the table came from.
        table: the parsed table.
        section: its name ("render", "rig.camera", "section[1].pma[0]"; None: the file's top level).
        dotted: name keys by their quoted dotted path (``'section[1].EI_Nm2'``) instead of
            ``[section] key``; for files made of arrays of tables.
        error: the error class raised (a subclass of ConfigFileError).
        key_word: what precedes a key's name in a value error ("key " by default: ``key [render]
            seed: ...``; the bench's files say just ``[render] seed: ...``, as they always have).

    Call :meth:`done` after the last :meth:`take` so that a misspelt (unknown) key is an error too.
    """

    def __init__(self, path: str | Path, table: dict[str, Any], section: str | None = None, *,
                 dotted: bool = False, error: type[ConfigFileError] = ConfigFileError, key_word: str = "key ") -> None:
        self.path, self.section, self.dotted = Path(path), section, dotted
        self.error_type, self.key_word = error, key_word
        if not isinstance(table, dict):
            raise self.fail(f"{self.table_name()}: expected a table, got {describe(table)}")
        self._table = table
        self._taken: set[str] = set()

    # --- names and errors ------------------------------------------------------------------------

    def name(self, key: str | None = None) -> str:
        """How messages name ``key`` of this table (the table itself when None)."""
        if self.dotted:
            parts = [p for p in (self.section, key) if p]
            return f"'{'.'.join(parts)}'"
        if key is None:
            return f"[{self.section}]" if self.section else "the top level"
        return f"[{self.section}] {key}" if self.section else key

    def table_name(self, key: str | None = None) -> str:
        """The name of this table, or of its sub-table ``key``, as a header (``[rig.camera]``) or dotted path."""
        child = self.child(key) if key is not None else self.section
        if self.dotted:
            return f"'{child}'" if child else "the top level"
        return f"[{child}]" if child else "the top level"

    def child(self, key: str) -> str:
        """The section name of the sub-table ``key``."""
        return f"{self.section}.{key}" if self.section else key

    def fail(self, message: str) -> ConfigFileError:
        """An error about the file: ``<file>: <message>`` (the message names the key itself)."""
        return self.error_type(f"{self.path}: {message}")

    def error(self, key: str, message: str) -> ConfigFileError:
        """An error about one key's value: ``<file>: key <key>: <message>``."""
        return self.fail(f"{self.key_word}{self.name(key)}: {message}")

    def missing(self, key: str) -> ConfigFileError:
        return self.fail(f"missing key {self.name(key)}")

    # --- reading ---------------------------------------------------------------------------------

    def has(self, key: str) -> bool:
        return key in self._table

    def keys(self) -> list[str]:
        return list(self._table)

    def raw(self, key: str, default: Any = _MISSING) -> Any:
        """The value of ``key`` as TOML gave it (marked as taken)."""
        self._taken.add(key)
        if key not in self._table:
            if default is _MISSING:
                raise self.missing(key)
            return default
        return self._table[key]

    def take(self, key: str, convert: Callable[[Any], Any], default: Any = _MISSING) -> Any:
        """``convert(value)`` of ``key``; ``default`` when the key is left out (required without one).

        Raises:
            ConfigFileError: the key is missing (and has no default), or ``convert`` raised
                TypeError/ValueError (its message follows the key's name).
        """
        self._taken.add(key)
        if key not in self._table:
            if default is _MISSING:
                raise self.missing(key)
            return default
        try:
            return convert(self._table[key])
        except (TypeError, ValueError) as e:
            if isinstance(e, ConfigFileError):
                raise
            raise self.error(key, str(e)) from e

    def sub(self, key: str, *, required: bool = True) -> TableReader | None:
        """The nested table ``key`` (``[key]`` at the top level, ``[section.key]`` below); None when it is
        optional (``required=False``) and absent."""
        self._taken.add(key)
        if key not in self._table:
            if required:
                raise self.fail(f"missing table {self.table_name(key)}")
            return None
        value = self._table[key]
        if not isinstance(value, dict):
            raise self.error(key, f"expected a table {self.table_name(key)}, got {describe(value)}")
        return self._reader(value, self.child(key))

    def tables(self, key: str, *, what: str = "") -> list[TableReader]:
        """The array of tables ``[[key]]``, one reader each (named ``key[0]``, ``key[1]``, ...).

        Raises:
            ConfigFileError: the key is missing, or not an array of tables (``what`` says what one holds).
        """
        self._taken.add(key)
        hint = f" ({what})" if what else ""
        if key not in self._table:
            raise self.fail(f"missing key {self.name(key)}{hint}")
        items = self._table[key]
        if not isinstance(items, list) or not items:
            raise self.error(key, f"expected an array of tables{hint}, got {describe(items)}")
        readers = []
        for i, item in enumerate(items):
            name = f"{self.child(key)}[{i}]"
            if not isinstance(item, dict):
                raise self.error(f"{key}[{i}]", f"expected a table, got {describe(item)}")
            readers.append(self._reader(item, name))
        return readers

    def _reader(self, table: dict, section: str) -> TableReader:
        return TableReader(self.path, table, section, dotted=self.dotted, error=self.error_type, key_word=self.key_word)

    def only(self, known: Iterable[str]) -> None:
        """Refuse a key that is not in ``known`` (before any value is taken), naming the closest known one."""
        known = list(known)
        for key in self._table:
            if key not in known:
                raise self._unknown(key, known)

    def done(self) -> None:
        """Refuse the keys no ``take``/``sub`` asked for (a misspelt key)."""
        unknown = [key for key in self._table if key not in self._taken]
        if unknown:
            raise self._unknown(unknown[0], sorted(self._taken), others=unknown[1:])

    def _unknown(self, key: str, known: list[str], others: Iterable[str] = ()) -> ConfigFileError:
        close = difflib.get_close_matches(key, known, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        others = list(others)
        more = f" (and {', '.join(others)})" if others else ""
        return self.fail(f"unknown key {self.name(key)}{more}{hint} (known keys: {', '.join(known) or 'none'})")


# --- converters: each takes a TOML value, returns it checked, or raises TypeError/ValueError ----------


def describe(value: Any) -> str:
    """A TOML value and its kind, for messages: ``'30' (a string)``."""
    kinds = {bool: "a boolean", int: "an integer", float: "a number", str: "a string", list: "an array",
             dict: "a table"}
    return f"{value!r} ({kinds.get(type(value), type(value).__name__)})"


def is_number(value: Any) -> bool:
    """A TOML integer or float (not a boolean)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def number(lo: float = -math.inf, hi: float = math.inf, *, lo_open: bool = False) -> Callable[[Any], float]:
    """A finite number in [lo, hi] (or (lo, hi] with ``lo_open``)."""

    def convert(value: Any) -> float:
        if not is_number(value):
            raise TypeError(f"expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value) or value > hi or value < lo or (lo_open and value == lo):
            bound = f"({lo}, {hi}]" if lo_open else f"[{lo}, {hi}]"
            raise ValueError(f"expected a number in {bound}, got {value!r}")
        return value

    return convert


def integer(lo: int, hi: int) -> Callable[[Any], int]:
    """An integer in [lo, hi] (a float or a boolean is refused)."""

    def convert(value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"expected an integer, got {value!r}")
        if not lo <= value <= hi:
            raise ValueError(f"expected an integer in [{lo}, {hi}], got {value}")
        return int(value)

    return convert


def vector(n: int | tuple[int, ...], lo: float = -math.inf, hi: float = math.inf) -> Callable[[Any], np.ndarray]:
    """A list of ``n`` finite numbers in [lo, hi] (``n`` may list the allowed lengths), as a float64 array."""
    lengths = (n,) if isinstance(n, int) else n

    def convert(value: Any) -> np.ndarray:
        if not isinstance(value, list) or not all(is_number(v) for v in value):
            raise TypeError(f"expected a list of numbers, got {value!r}")
        if len(value) not in lengths:
            raise ValueError(f"expected {' or '.join(map(str, lengths))} numbers, got {len(value)}")
        array = np.asarray(value, dtype=np.float64)
        if not np.all(np.isfinite(array)) or np.any(array < lo) or np.any(array > hi):
            raise ValueError(f"expected finite numbers in [{lo}, {hi}], got {value!r}")
        return array

    return convert


def boolean(value: Any) -> bool:
    """true or false (not 0 or 1)."""
    if not isinstance(value, bool):
        raise TypeError(f"expected true or false, got {value!r}")
    return value


def text(value: Any) -> str:
    """A non-empty string."""
    if not isinstance(value, str) or not value.strip():
        raise TypeError(f"expected a non-empty string, got {value!r}")
    return value


def choice(options: Iterable[str]) -> Callable[[Any], str]:
    """One of ``options``."""
    options = tuple(options)

    def convert(value: Any) -> str:
        if value not in options:
            raise ValueError(f"expected one of {', '.join(map(repr, options))}, got {value!r}")
        return value

    return convert


def file_in(folder: Path) -> Callable[[Any], Path]:
    """A file name; relative names resolve against ``folder`` (the folder of the file that names it)."""

    def convert(value: Any) -> Path:
        if not isinstance(value, str) or not value.strip():
            raise TypeError(f"expected a file name, got {value!r}")
        path = Path(value).expanduser()
        return path if path.is_absolute() else Path(folder) / path

    return convert
