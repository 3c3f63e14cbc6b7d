"""Griffe extension for smo_gym's documentation: two conventions of the code that griffe does not read itself.

* ``#:`` comments right above a module or class attribute document it (Sphinx autodoc's convention, used for
  the registries and constants: ``#: name -> class, for the wrapper, ...``); griffe reads only string literals
  after an assignment. A ``#:`` comment becomes the attribute's docstring when it has none.
* ``__doc__ = Other.__doc__`` in a class body shares a docstring (``ILFFixedDifferentiator``); griffe analyses
  the source statically and does not evaluate it. The class gets ``Other``'s docstring.
"""

from __future__ import annotations

import griffe


class SmoGymConventions(griffe.Extension):
    """Read ``#:`` attribute comments and ``__doc__ = Other.__doc__`` (see the module docstring)."""

    def on_attribute_instance(self, *, attr: griffe.Attribute, **kwargs) -> None:
        if attr.docstring is not None or attr.lineno is None:
            return
        try:
            lines = attr.parent.lines if attr.parent.is_module else attr.module.lines
        except (AttributeError, OSError):
            return
        comment = []
        k = attr.lineno - 2  # the line above the assignment, 0-based
        while k >= 0 and lines[k].strip().startswith("#:"):
            comment.insert(0, lines[k].strip()[2:].strip())
            k -= 1
        if comment:
            attr.docstring = griffe.Docstring("\n".join(comment), lineno=k + 2, parent=attr)

    def on_class_members(self, *, cls: griffe.Class, **kwargs) -> None:
        shared = cls.members.get("__doc__")
        if cls.docstring is not None or shared is None or not isinstance(shared, griffe.Attribute):
            return
        value = str(shared.value or "")
        if not value.endswith(".__doc__"):
            return
        source = cls.parent.members.get(value[: -len(".__doc__")])
        if source is not None and source.docstring is not None:
            cls.docstring = griffe.Docstring(source.docstring.value, lineno=source.docstring.lineno, parent=cls)
