"""Where mjData keeps its contacts, so a compiled loop can read them after each mj_step2 without Python.

A numba kernel that runs a whole control period (envs.sim.period_kernel) must read the contacts of every physics step
(ncon, the mjContact array, efc_force) from the mjData pointer itself: the Python bindings' views of them
(``data.contact.geom``, ``data.efc_force``) are rebuilt by Python after each step. The byte offsets of those fields
come from the C struct definitions that the ``mujoco`` package ships (``mujoco.introspect``, generated from the
headers of the same release), laid out with ctypes (the C compiler's alignment rules), and are then checked against
the bindings on a live mjData (`check_layout`): a release whose structs differ from its introspection fails loudly
instead of reading the wrong bytes.

    DATA_NCON, DATA_NEFC         int fields of mjData
    DATA_CONTACT, DATA_EFC_FORCE pointer fields of mjData (mjContact*, mjtNum*)
    DATA_EFC_TYPE, DATA_EFC_ID   pointer fields of mjData (int*): each constraint row's type and object (the
                                 joint-torque sensing tells the joints' friction rows from the contacts')
    CONTACT_SIZE                 sizeof(mjContact)
    CONTACT_GEOM, CONTACT_EFC_ADDRESS   offsets of int geom[2] and int efc_address in mjContact

The values are slots of the int64 array `LAYOUT` (LAYOUT_* indices) that kernels receive.
"""

from __future__ import annotations

import ctypes
import math
from functools import lru_cache
from typing import Any

import mujoco
import numpy as np
from mujoco.introspect import ast_nodes, structs

from controllers.errors import ControllerError

(LAYOUT_NCON, LAYOUT_NEFC, LAYOUT_CONTACT, LAYOUT_EFC_FORCE, LAYOUT_CONTACT_SIZE, LAYOUT_GEOM, LAYOUT_EFC_ADDRESS,
 LAYOUT_EFC_TYPE, LAYOUT_EFC_ID) = range(9)

_SCALARS: dict[str, Any] = {
    "int": ctypes.c_int, "unsigned int": ctypes.c_uint, "mjtNum": ctypes.c_double, "double": ctypes.c_double,
    "float": ctypes.c_float, "mjtSize": ctypes.c_int64, "size_t": ctypes.c_size_t, "uintptr_t": ctypes.c_size_t,
    "mjtBool": ctypes.c_ubyte, "mjtByte": ctypes.c_ubyte, "char": ctypes.c_char, "int64_t": ctypes.c_int64,
    "uint64_t": ctypes.c_uint64,
}


def _ctype(node: Any) -> Any:
    """The ctypes type of an introspection type node (pointers are void*: only their address is read)."""
    if isinstance(node, ast_nodes.PointerType):
        return ctypes.c_void_p
    if isinstance(node, ast_nodes.ArrayType):
        return _ctype(node.inner_type) * math.prod(node.extents)
    if isinstance(node, ast_nodes.ValueType):
        if node.name in _SCALARS:
            return _SCALARS[node.name]
        if node.name in structs.STRUCTS:
            return _struct(node.name)
    raise ControllerError(f"mujoco.introspect type {node} has no ctypes layout here")


@lru_cache(maxsize=None)
def _struct(name: str) -> Any:
    """A ctypes.Structure with the fields of the introspected struct ``name``."""
    fields = [(f.name, _ctype(f.type)) for f in structs.STRUCTS[name].fields]
    return type(name, (ctypes.Structure,), {"_fields_": fields})


@lru_cache(maxsize=1)
def _layout() -> np.ndarray:
    data, contact = _struct("mjData"), _struct("mjContact")
    values = [data.ncon.offset, data.nefc.offset, data.contact.offset, data.efc_force.offset, ctypes.sizeof(contact),
              contact.geom.offset, contact.efc_address.offset, data.efc_type.offset, data.efc_id.offset]
    table = np.array(values, dtype=np.int64)
    table.flags.writeable = False
    return table


def layout() -> np.ndarray:
    """The LAYOUT_* byte offsets and sizes (read-only int64 array) from the installed release's introspection.

    Raises:
        ControllerError: a field type the introspection uses that has no ctypes layout here.
    """
    return _layout()


def check_layout(data: mujoco.MjData) -> np.ndarray:
    """`layout`, checked against the bindings on ``data``: the int and pointer fields read at the offsets must be
    ncon, nefc and (when there are constraints and contacts) the addresses of efc_force, efc_type, efc_id and the
    contact array, and the mjContact offsets those of the bindings' views. Check it on a state with contacts to check
    every offset.

    Raises:
        ControllerError: any mismatch (this release's structs are not what its introspection says).
    """
    table = layout()
    base = data._address

    def read(offset: int, ctype: Any) -> int:
        return int(ctype.from_address(base + int(offset)).value or 0)

    found = {"ncon": read(table[LAYOUT_NCON], ctypes.c_int), "nefc": read(table[LAYOUT_NEFC], ctypes.c_int)}
    expected = {"ncon": data.ncon, "nefc": data.nefc}
    if data.nefc > 0:  # an empty efc_force may be NULL in mjData while the bindings hand out an empty array
        for name, slot in (("efc_force", LAYOUT_EFC_FORCE), ("efc_type", LAYOUT_EFC_TYPE), ("efc_id", LAYOUT_EFC_ID)):
            found[name] = read(table[slot], ctypes.c_void_p)
            expected[name] = getattr(data, name).ctypes.data
    contact = read(table[LAYOUT_CONTACT], ctypes.c_void_p)
    if data.ncon > 0:
        views = data.contact
        found.update(contact=contact, contact_size=int(table[LAYOUT_CONTACT_SIZE]),
                     geom=contact + int(table[LAYOUT_GEOM]), efc_address=contact + int(table[LAYOUT_EFC_ADDRESS]))
        expected.update(contact=views.dist.ctypes.data, contact_size=views.geom.strides[0],
                        geom=views.geom.ctypes.data, efc_address=views.efc_address.ctypes.data)
    wrong = [f"{k} {found[k]} != {expected[k]}" for k in expected if found[k] != expected[k]]
    if wrong:
        raise ControllerError(f"mujoco {mujoco.__version__}: mjData layout from mujoco.introspect does not match the "
                              f"bindings ({', '.join(wrong)})")
    return table
