"""Config files: JSON presets (load/save, schema version), the original DataPipe pickle read through
an unpickler that refuses every class, and the package's presets and assets."""
from __future__ import annotations

import io
import json
import os
import pickle
from pathlib import Path

from ..errors import ConfigError, DataPipeError, Problem
from ..io.input_files import MAX_JSON_BYTES, read_regular
from ..io.files import write_text_atomic
from .pickle_depth import pickle_depth
from .legacy import from_legacy_dict
from .limits import MAX_PICKLE_NESTING
from .schema import Config


def save(cfg: Config, path: str | os.PathLike) -> None:
    """Write a JSON preset atomically (write, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(cfg.to_dict(), indent=2) + "\n")


def loads(text: str, *, base_dir=None) -> Config:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise ConfigError(Problem("<file>", f"not valid JSON: {e}", "fix the JSON syntax at the line shown")) from None
    except RecursionError:
        raise ConfigError(Problem("<file>", "JSON nested too deeply to be a preset",
                                  "give a preset: a few levels of objects and lists")) from None
    except ValueError:                         # an integer of more than 4,300 digits (Python's limit)
        raise ConfigError(Problem("<file>", "cannot read a number: an integer of more than 4,300 digits",
                                  "give numbers of a sensible size (no field needs more than 20 digits)")) from None
    return Config.from_dict(data, base_dir=base_dir)


def load(path: str | os.PathLike) -> Config:
    """Load a JSON preset or an original-layout DataPipe pickle (detected by content)."""
    path = Path(path)
    if not os.path.exists(path):
        raise ConfigError(Problem("<file>", f"preset not found: {path}", "give the path of a .json preset or .pickle"))
    try:                                 # a FIFO or device is refused before a byte is read
        raw = read_regular(path, MAX_JSON_BYTES)
    except DataPipeError as e:
        raise ConfigError(Problem("<file>", str(e), "give a .json preset or .pickle (a regular file within the "
                                  "limit in docs/INPUT_LIMITS.md)")) from None
    if raw[:1] == b"\x80" or path.suffix.lower() in (".pickle", ".pkl"):
        return load_legacy_pickle(raw, base_dir=path.parent)
    try:
        text = raw.decode("utf-8-sig")         # a BOM (Windows editors) is not a JSON error
    except UnicodeDecodeError:
        raise ConfigError(Problem("<file>", f"{path} is neither JSON nor a pickle", "give a .json preset")) from None
    return loads(text, base_dir=path.parent)


class _RefusingUnpickler(pickle.Unpickler):
    """Plain containers and numbers only: any class or callable (the way a pickle runs code) is refused."""

    def find_class(self, module, name):
        raise ConfigError(Problem("<pickle>", f"refused to load {module}.{name}: a DataPipe preset holds only "
                                  "dicts, lists, numbers and strings", "load only presets you trust; re-save "
                                  "it as JSON"))


def load_legacy_pickle(raw: bytes, *, base_dir=None) -> Config:
    depth = pickle_depth(raw, MAX_PICKLE_NESTING)
    if depth is not None and depth > MAX_PICKLE_NESTING:     # before unpickling: deep tuples crash hash()
        raise ConfigError(Problem("<pickle>", f"containers nested more than {MAX_PICKLE_NESTING} levels deep: "
                                  "no DataPipe inputs pickle is", "give an original DataPipe inputs pickle "
                                  "(5 levels) or a JSON preset"))
    try:
        data = _RefusingUnpickler(io.BytesIO(raw)).load()
    except ConfigError:
        raise
    except MemoryError:     # a length field (BINBYTES8, ...) larger than memory: corrupt or hostile
        raise ConfigError(Problem("<pickle>", f"cannot read the pickle: it declares a value larger than the "
                                  f"memory ({len(raw)} bytes in the file)", "give an original DataPipe inputs "
                                  "pickle or a JSON preset; this one is damaged")) from None
    except Exception as e:  # truncated or corrupt pickles raise many types
        reason = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
        raise ConfigError(Problem("<pickle>", f"cannot read the pickle ({reason})", "give an original DataPipe "
                                  "inputs pickle or a JSON preset")) from None
    cfg = from_legacy_dict(data)
    if base_dir is not None:
        cfg.resolve_paths(base_dir)
    return cfg


def assets_dir() -> Path:
    return Path(__file__).resolve().parents[1] / "assets"


def presets_dir() -> Path:
    return Path(__file__).resolve().parents[1] / "presets"


def default_config() -> Config:
    """The embedded demo: a small bin with a few small parts, low resolution, 2 scenes."""
    return load(presets_dir() / "default.json")
