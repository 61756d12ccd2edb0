"""Which strings a preset may hold where they reach the file system or Blender. No bpy.

A path or a name that Python's `str` holds can still be refused later, after files were written:
- the OS takes no NUL byte in a path (`ValueError: embedded null byte`) and no lone surrogate
  (`"\\ud800"`: UTF-8 cannot encode it; `os.fsencode` raises `UnicodeEncodeError`);
- Blender refuses a lone surrogate in an ID name (`TypeError ... surrogates not allowed`), silently
  cuts a name at a NUL byte (`"x\\x00y"` becomes `"x"`), and cuts names longer than its ID name
  buffer: 63 bytes of UTF-8 up to Blender 4.5, 255 from 5.0 (on the 5.0.1 wheel a 255-byte name
  is kept and a 256-byte one comes back shorter), after which an instance's name is no longer the
  one its annotations carry. Control characters (tab, newline) Blender takes, but they break the
  one-line progress and log output and no one means them in a name: refused too.
So `validate()` checks these rules for every path and every name before any work.
"""
from __future__ import annotations

import os
import unicodedata

MAX_ID_NAME_BYTES = 63      # Blender 4.2-4.5's ID names; a preset must run on 4.2 and 5.x alike


def short(value) -> str:
    """A bad value for a message: scalars as written (cut at 80 characters, lone surrogates escaped),
    containers by type (their repr may be huge or nested deeper than repr can go)."""
    if value is None or isinstance(value, (bool, int, float, str, bytes)):
        try:
            text = repr(value)
        except ValueError:                     # an int with more digits than repr allows
            text = "a very long integer"
        text = text.encode("utf-8", "backslashreplace").decode("utf-8")   # printable on any terminal
        return text if len(text) <= 80 else text[:77] + "..."
    return f"a {type(value).__name__}"


def _bad_character(text: str) -> str | None:
    """What makes `text` unusable as a path or name: a NUL, a lone surrogate, a control character."""
    for ch in text:
        if ch == "\x00":
            return "a NUL character (\\x00)"
        if "\ud800" <= ch <= "\udfff":
            return f"a lone surrogate (U+{ord(ch):04X}) that UTF-8 cannot encode"
        if unicodedata.category(ch) == "Cc":
            return f"a control character (U+{ord(ch):04X})"
    return None


def path_problem(text: str) -> tuple[str, str] | None:
    """(what is wrong, the fix) for a path the OS cannot take, else None.

    Control characters other than NUL are legal in POSIX paths, so only the two the OS refuses
    are refused here. A surrogate escape (U+DC80..U+DCFF, how Python holds a non-UTF-8 byte of a
    file name) encodes back to that byte and is accepted."""
    if "\x00" in text:
        return "contains a NUL character (\\x00), which no file path can hold", \
            "remove it from the path; a JSON \"\\u0000\" is a NUL"
    try:
        os.fsencode(text)
    except UnicodeEncodeError as e:
        ch = text[e.start]
        return f"contains a character the file system cannot encode (U+{ord(ch):04X}, a lone surrogate)", \
            "write the path in plain UTF-8; a JSON \"\\ud800\" without its pair is not a character"
    return None


def output_folder_problem(text: str) -> tuple[str, str] | None:
    """path_problem, and braces: Blender 5 reads '{...}' in a File Output path as a template and
    skips the write (core/compat.set_file_output_path refuses it, but only once the run has begun)."""
    problem = path_problem(text)
    if problem is None and ("{" in text or "}" in text):
        problem = (f"{short(text)} holds a brace: Blender 5 reads '{{...}}' in the path of the files it "
                   "renders as a template and skips the write", "choose an output folder without '{' or '}'")
    return problem


def name_problem(text: str, *, prefix: str = "", suffix: str = "") -> tuple[str, str] | None:
    """(what is wrong, the fix) for a name Blender cannot hold as given, else None. `prefix` and
    `suffix` are what DataPipe adds around it (an instance number, a material prefix): the whole
    ID name must fit MAX_ID_NAME_BYTES."""
    bad = _bad_character(text)
    if bad is not None:
        return f"{short(text)} contains {bad}, which a Blender name cannot hold", \
            "use printable characters only"
    extra = len((prefix + suffix).encode("utf-8"))
    size = len(text.encode("utf-8"))
    if size + extra > MAX_ID_NAME_BYTES:
        added = f" ({prefix + '...' if prefix else ''}{'...' + suffix if suffix else ''} added by DataPipe)" \
            if extra else ""
        return f"{short(text)} is {size} bytes of UTF-8: the Blender name{added} would have {size + extra}, and " \
               f"Blender 4.x cuts names at {MAX_ID_NAME_BYTES} bytes (the objects would not carry the names " \
               "the annotations give)", f"give a name of at most {MAX_ID_NAME_BYTES - extra} bytes"
    return None
