"""Bytes handed to pyarrow without a Python object inside (issue 33)."""

from __future__ import annotations

import pyarrow as pa


def arrow_reader(data: bytes) -> pa.BufferReader:
    """A reader of ``data`` for pyarrow over a copy Arrow owns. Given Python bytes (or a
    Python file), Arrow keeps a reference to a Python object in what it reads, and a
    scan may drop its last reference from one of Arrow's own threads, which then takes
    the GIL: during the interpreter's exit that thread is made to exit, and the unwind
    through Arrow's C++ ends in ``std::terminate`` (issue 33: ``idda verify`` aborted,
    exit 134, "terminate called without an active exception"). A copy holds no Python object."""
    return pa.BufferReader(_owned(data))


_NUMBERS = {pa.int16(): "int16", pa.int32(): "int32", pa.int64(): "int64", pa.float32(): "float32",
            pa.float64(): "float64"}


def _owned(array) -> pa.Buffer:
    """A buffer Arrow owns (no Python object inside, see :func:`arrow_reader`) holding ``array``'s bytes."""
    data = memoryview(array).cast("B")
    buffer = pa.allocate_buffer(len(data))
    memoryview(buffer).cast("B")[:] = data
    return buffer


def arrow_column(values: list, kind: pa.DataType, name: str = "column") -> pa.Array:
    """The Arrow array ``pa.array(values, type=kind)`` gives, for the types tables of frames use
    (int16/32/64, float32/64, string, fixed-size lists of float64; None is null), built from
    numpy buffers.

    Not ``pa.array``: to check whether its input is a pandas object it imports pandas, ~0.25 CPU-s
    in each render worker (a frame's objects table, an episode's part) that nothing else there
    needs. Values convert as ``pa.array`` converts them: an integer out of the type's range, a
    string column's non-string or a list of the wrong length raises ValueError; a float rounds to
    float32. As ``pa.array``, no validity bitmap unless a value is None."""
    import numpy as np

    types = set(map(type, values))  # the checks per kind of value, not per value
    nulls = sum(v is None for v in values) if type(None) in types else 0
    missing = np.fromiter((v is None for v in values), bool, len(values)) if nulls else None
    validity = _owned(np.packbits(~missing, bitorder="little")) if nulls else None
    present = [v for v in values if v is not None] if nulls else values
    if kind in _NUMBERS:
        if any(issubclass(t, (str, bytes, bool, np.bool_)) for t in types):
            raise ValueError(f"{name}: expected numbers for {kind}, got {present!r:.80}")
        if pa.types.is_integer(kind) and any(issubclass(t, (float, np.floating)) for t in types) and any(
                isinstance(v, (float, np.floating)) and not float(v).is_integer() for v in present):
            raise ValueError(f"{name}: a fraction in an integer column: {present!r:.80}")
        try:
            dense = np.asarray(present, _NUMBERS[kind]) if present else np.zeros(0, _NUMBERS[kind])
            if nulls:
                dense, given = np.zeros(len(values), _NUMBERS[kind]), dense
                dense[~missing] = given
        except (OverflowError, TypeError, ValueError) as exc:
            raise ValueError(f"{name}: {exc}") from None
        return pa.Array.from_buffers(kind, len(values), [validity, _owned(dense)], null_count=nulls)
    if kind == pa.string():
        if not all(issubclass(t, str) for t in types - {type(None)}):
            raise ValueError(f"{name}: expected strings, got {present!r:.80}")
        data = [b"" if v is None else v.encode() for v in values]
        offsets = np.zeros(len(data) + 1, np.int32)
        np.cumsum([len(d) for d in data], out=offsets[1:])
        text = np.frombuffer(b"".join(data) or b"\0", np.uint8)
        return pa.Array.from_buffers(kind, len(values), [validity, _owned(offsets), _owned(text)],
                                     null_count=nulls)
    if pa.types.is_fixed_size_list(kind) and kind.value_type == pa.float64():
        size = kind.list_size
        rows = np.zeros((len(values), size), np.float64)
        for i, v in enumerate(values):
            if v is not None:
                row = np.asarray(v, np.float64).ravel()
                if row.shape != (size,):
                    raise ValueError(f"{name}: expected lists of {size} numbers, got {len(row)}")
                rows[i] = row
        child = pa.Array.from_buffers(pa.float64(), rows.size, [None, _owned(rows)])
        return pa.Array.from_buffers(kind, len(values), [validity], null_count=nulls, children=[child])
    raise ValueError(f"{name}: no column builder for {kind}")


def arrow_table(columns: dict[str, list], schema: pa.Schema) -> pa.Table:
    """``pa.table(columns, schema=schema)`` without importing pandas (see :func:`arrow_column`)."""
    return pa.Table.from_arrays([arrow_column(columns[f.name], f.type, f.name) for f in schema], schema=schema)
