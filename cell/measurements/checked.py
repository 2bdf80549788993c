"""Model files checked twice over, cheaply: the base of the dataclasses that hold a
``model.yaml`` (planar :class:`~cell.measurements.campaign.ModelSpec`, chain
:class:`~cell.measurements.chain_spec.ChainSpec` and their parts).

pydantic defines what is valid and says what is wrong, but importing it and building the
models costs about 0.08 s of CPU, most of a diagnosis' start-up. So each class has a plain
check of its own for input that is *plainly* valid (known keys, the types the model
names, finite numbers; no conversion beyond int → float and list → tuple), and only the
rest is handed to its pydantic model, built on first use, which converts what it accepts
and raises its ValidationError, with its message, for the rest. A test holds the two
paths to the same answers (``tests/cell/test_chain_spec_paths.py``,
``tests/cell/test_measurements_fast.py``), with the plain checks switched off by
:func:`pydantic_only`.
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import fields

_plain_checks = True


@contextmanager
def pydantic_only():
    """Within the block, every model file is checked by its pydantic model alone (the plain
    checks are switched off, for the whole process): what a check of the two paths holds
    the plain one against. Not for use while other threads read model files."""
    global _plain_checks
    was, _plain_checks = _plain_checks, False
    try:
        yield
    finally:
        _plain_checks = was


def plain(check, data) -> dict | None:
    """``check(data)``: the fields of plainly valid input, or None (then pydantic decides);
    always None inside :func:`pydantic_only`."""
    return check(data) if _plain_checks else None


class PlainFirst:
    """Base of such a dataclass, named with its two checks as class keywords:
    ``class Row(PlainFirst, plain=check, pydantic=model)``, ``check(mapping)`` giving its
    fields or None when the input is not plainly valid, ``model()`` its pydantic model. A
    subclass may override ``_from_pydantic`` (the model's result as fields) and
    ``as_input`` (the fields as the file holds them). Construction and
    :meth:`model_validate` check the input; bad input raises pydantic's ValidationError."""

    def __init_subclass__(cls, plain=None, pydantic=None, **kw):
        super().__init_subclass__(**kw)
        if plain is None or pydantic is None:
            raise TypeError(f"{cls.__name__}: name its plain= check and its pydantic= model")
        cls._plain, cls._pydantic = staticmethod(plain), staticmethod(pydantic)

    @classmethod
    def _from_pydantic(cls, m) -> dict:
        return dict(m)

    @classmethod
    def _fields(cls, data) -> dict:
        out = plain(cls._plain, data)
        return out if out is not None else cls._from_pydantic(cls._pydantic().model_validate(data))

    def as_input(self) -> dict:
        """The fields as the file holds them."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def __post_init__(self):
        self.__dict__.update(self._fields(self.as_input()))

    @classmethod
    def model_validate(cls, data):
        """An instance from a mapping (as ``model.yaml`` holds it); unknown keys and bad
        values raise pydantic's ValidationError."""
        return cls(**cls._fields(data))
