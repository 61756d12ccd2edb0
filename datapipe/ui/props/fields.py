"""What the property groups share: the Config defaults they read, enum items, the update callbacks
that keep paired limits ordered and the viewport previews in step, the [min, max] range property and
the material search."""
import dataclasses

from bpy.props import FloatVectorProperty


def default(dc, name: str):
    """The Config dataclass default of `dc.name` (default or default_factory)."""
    for f in dataclasses.fields(dc):
        if f.name == name:
            if f.default is not dataclasses.MISSING:
                return f.default
            return f.default_factory()
    raise KeyError(f"{dc.__name__} has no field {name!r}")


def enum_choices(values, descriptions=None):
    """EnumProperty items for Config's allowed values: (value, Title Case label, description)."""
    descriptions = descriptions or {}
    return [(v, v.replace("_", " ").title(), descriptions.get(v, v)) for v in values]


# ------------------------------------------------------------------------------------------------
# update callbacks

def keep_order(lo: str, hi: str, *, strict: bool = False):
    """Two update callbacks keeping `lo <= hi` (or `lo < hi` when strict) by moving the other one."""
    def lo_changed(self, context):
        a, b = getattr(self, lo), getattr(self, hi)
        if a > b or (strict and a >= b):
            setattr(self, hi, a * 2 if strict else a)

    def hi_changed(self, context):
        a, b = getattr(self, lo), getattr(self, hi)
        if a > b or (strict and a >= b):
            setattr(self, lo, b / 2 if strict else b)

    return lo_changed, hi_changed


def keep_range(name: str):
    """An update callback keeping a [min, max] vector property ordered (swaps an inverted pair)."""
    def changed(self, context):
        lo, hi = getattr(self, name)
        if lo > hi:
            setattr(self, name, (hi, lo))
    return changed


def range_property(name: str, label: str, description: str, dc, *, unit="NONE", lo=None, hi=None,
                   soft_max=None, precision=3):
    """A [min, max] FloatVectorProperty (size 2) for Config field `name` of dataclass `dc`."""
    kw = {"min": lo} if lo is not None else {}
    if hi is not None:
        kw["max"] = hi
    if soft_max is not None:
        kw["soft_max"] = soft_max
    return FloatVectorProperty(name=label, description=description + " (min, max)", size=2, unit=unit,
                               default=default(dc, name), precision=precision, update=keep_range(name), **kw)


def material_search(edit_text):
    """Preset names for the material fields (unknown text is reported by Config.validate())."""
    from ...materials_spec import NAMES
    return [n for n in NAMES if edit_text.lower() in n.lower()]


def sync_previews(self, context):
    """Keep the viewport previews (camera, projector, object) in step with edited properties."""
    from .. import preview
    preview.sync(context)


def chain(*callbacks):
    def run(self, context):
        for cb in callbacks:
            cb(self, context)
    return run
