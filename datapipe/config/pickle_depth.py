"""How deeply a pickle nests its containers, read from its opcodes without building anything. No bpy.

Unpickling a deeply nested structure is safe in itself (the unpickler is a loop), but some C code
that then touches it recurses without Python's recursion check: a dict key or set item that is a
tuple nested deep is hashed by `tuplehash` calling itself. Measured on CPython 3.11 with an 8 MB
stack, `{((((...1,),),),): 2}` with 100,000 tuples loads and with 150,000 the process dies with a
segmentation fault (a thread with a smaller stack dies sooner). `config.load_legacy_pickle`
therefore measures the depth first and refuses what no preset needs (past 1,000 levels: at most
~70 kB of that recursion). The opcodes run on a stack of depths (a scalar 0, a container 1 + its
deepest item); opcodes that build objects (GLOBAL, REDUCE, ...) end the scan: the refusing
unpickler refuses them.
"""
from __future__ import annotations

import pickletools

_SCALAR_OPS = {"INT", "BININT", "BININT1", "BININT2", "LONG", "LONG1", "LONG4", "STRING", "BINSTRING",
               "SHORT_BINSTRING", "BINBYTES", "SHORT_BINBYTES", "BINBYTES8", "BYTEARRAY8", "NONE", "NEWTRUE",
               "NEWFALSE", "UNICODE", "SHORT_BINUNICODE", "BINUNICODE", "BINUNICODE8", "FLOAT", "BINFLOAT"}
_EMPTY_OPS = {"EMPTY_DICT", "EMPTY_LIST", "EMPTY_TUPLE", "EMPTY_SET"}
_MARK = object()


def pickle_depth(raw: bytes, limit: int) -> int | None:
    """The deepest container nesting in `raw` (0: a scalar), counted up to `limit` + 1 (the scan
    stops there); None when the opcodes cannot be read or build objects (the unpickler says why).

    Each stack entry is a one-item list holding its depth, shared with the memo, so a container
    filled after it was memoized (APPEND after PUT) is deep wherever it is fetched again."""
    stack: list = []
    memo: dict = {}
    deepest = 0

    def pop_to_mark() -> list[int]:
        items = []
        while stack and stack[-1] is not _MARK:
            items.append(stack.pop()[0])
        if not stack:
            raise ValueError("no mark")
        stack.pop()
        return items

    def grow(depth: int) -> None:            # an item went into the container on top of the stack
        stack[-1][0] = max(stack[-1][0], 1 + depth)

    try:
        for op, arg, _pos in pickletools.genops(raw):
            name = op.name
            if name in _SCALAR_OPS:
                stack.append([0])
            elif name in _EMPTY_OPS:
                stack.append([1])
            elif name == "MARK":
                stack.append(_MARK)
            elif name in ("TUPLE", "LIST", "DICT", "FROZENSET"):
                stack.append([1 + max(pop_to_mark(), default=0)])
            elif name in ("TUPLE1", "TUPLE2", "TUPLE3"):
                items = [stack.pop()[0] for _ in range(int(name[-1]))]
                stack.append([1 + max(items)])
            elif name == "APPEND":
                grow(stack.pop()[0])
            elif name == "SETITEM":
                grow(max(stack.pop()[0], stack.pop()[0]))
            elif name in ("APPENDS", "SETITEMS", "ADDITEMS"):
                grow(max(pop_to_mark(), default=0))
            elif name in ("PUT", "BINPUT", "LONG_BINPUT"):
                memo[arg] = stack[-1]
            elif name == "MEMOIZE":
                memo[len(memo)] = stack[-1]
            elif name in ("GET", "BINGET", "LONG_BINGET"):
                stack.append(memo[arg])
            elif name == "POP":
                stack.pop()
            elif name == "POP_MARK":
                pop_to_mark()
            elif name == "DUP":
                stack.append(stack[-1])
            elif name == "STOP":
                break
            elif name not in ("PROTO", "FRAME"):     # builds objects: refused by the unpickler anyway
                return None
            if stack and stack[-1] is not _MARK:
                deepest = max(deepest, stack[-1][0])
                if deepest > limit:
                    return deepest
    except (ValueError, KeyError, IndexError, TypeError):   # truncated or malformed: the unpickler says why
        return None
    return deepest
