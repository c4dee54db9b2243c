"""MuJoCo's C API for numba kernels: a compiled loop calls mj_step1, mj_step2, mj_jac, mj_jacSite, mj_solveM,
mj_kinematics, mj_comPos, mj_integratePos, mju_mat2Quat and mj_objectVelocity itself instead of returning to Python
for each (a call through the Python bindings costs ~0.6 us more, and the Python around it several us per physics
step).

The functions are those of the libmujoco that the ``mujoco`` package loaded (same library, same model and data).
Kernels receive plain integers, so they stay cacheable (numba refuses to cache a function that holds a ctypes
function object, and unboxing one per call costs ~2 us):

    fns  = FUNCTIONS                 # int64 addresses, FN_* indices
    m, d = model._address, data._address
    arr.ctypes.data                  # an array's buffer; 0 for NULL

and call them through the intrinsics below, which jump to an address with the C signature of mujoco.h (MuJoCo 3):

    void mj_step1(const mjModel* m, mjData* d);           void mj_step2(const mjModel* m, mjData* d);
    void mj_jac(const mjModel* m, const mjData* d, mjtNum* jacp, mjtNum* jacr, const mjtNum point[3], int body);
    void mj_jacSite(const mjModel* m, const mjData* d, mjtNum* jacp, mjtNum* jacr, int site);
    void mj_solveM(const mjModel* m, mjData* d, mjtNum* x, const mjtNum* y, int n);
    void mj_kinematics(const mjModel* m, mjData* d);      void mj_comPos(const mjModel* m, mjData* d);
    void mj_integratePos(const mjModel* m, mjtNum* qpos, const mjtNum* qvel, mjtNum dt);
    void mju_mat2Quat(mjtNum quat[4], const mjtNum mat[9]);
    void mj_objectVelocity(const mjModel* m, const mjData* d, int objtype, int objid, mjtNum res[6], int flg_local);

The signatures are written here, not read from the library: tests/controllers/test_mujoco_c.py runs each call against
the Python bindings on random Panda states (bit for bit), so a MuJoCo whose signatures change fails the tests instead of
corrupting memory in an episode.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import mujoco
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from controllers.errors import ControllerError

(FN_STEP1, FN_STEP2, FN_JAC, FN_JAC_SITE, FN_SOLVE_M, FN_KINEMATICS, FN_COM_POS, FN_INTEGRATE_POS, FN_MAT2QUAT,
 FN_OBJECT_VELOCITY) = range(10)
_NAMES = ("mj_step1", "mj_step2", "mj_jac", "mj_jacSite", "mj_solveM", "mj_kinematics", "mj_comPos", "mj_integratePos",
          "mju_mat2Quat", "mj_objectVelocity")


def library_path() -> Path:
    """The libmujoco shared library inside the installed ``mujoco`` package.

    Raises:
        ControllerError: no such library there (a platform or an install this module does not know).
    """
    folder = Path(mujoco.__file__).parent
    found = sorted(folder.glob("libmujoco.so*")) + sorted(folder.glob("libmujoco*.dylib")) + sorted(
        folder.glob("mujoco.dll"))
    if not found:
        raise ControllerError(f"no libmujoco shared library in {folder}")
    return found[0]


def _function_table() -> np.ndarray:
    """int64 addresses of the FN_* functions in the loaded libmujoco (read-only)."""
    lib = ctypes.CDLL(str(library_path()))  # the library the bindings already loaded: the same handle
    table = np.array([ctypes.cast(getattr(lib, name), ctypes.c_void_p).value for name in _NAMES], dtype=np.int64)
    table.flags.writeable = False
    return table


FUNCTIONS: np.ndarray = _function_table()
"""The addresses of the FN_* functions, found once per process (a constant while the library stays loaded; looking
them up took ~0.24 ms, which every IK solve and controller construction paid)."""


_I64, _I32, _F64 = ir.IntType(64), ir.IntType(32), ir.DoubleType()
_C_TYPES = {"p": _I64, "i": _I32, "d": _F64}


def _jump(builder: ir.IRBuilder, address: ir.Value, args: list[ir.Value], kinds: str) -> None:
    """Call the void C function at ``address`` with ``args``: 'p' a pointer (an int64), 'i' a C int (an int64
    truncated), 'd' a double."""
    fnty = ir.FunctionType(ir.VoidType(), [_C_TYPES[k] for k in kinds])
    values = [builder.trunc(a, _I32) if k == "i" else a for a, k in zip(args, kinds)]
    builder.call(builder.inttoptr(address, fnty.as_pointer()), values)


@intrinsic
def call_md(typingctx, fn, m, d):  # type: ignore[no-untyped-def]
    """fn(m, d): mj_step1, mj_step2, mj_kinematics, mj_comPos; and any function of two pointers, e.g.
    mju_mat2Quat(quat, mat)."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        _jump(builder, args[0], list(args[1:]), "pp")
        return context.get_dummy_value()
    return types.none(types.int64, types.int64, types.int64), codegen


@intrinsic
def call_jac(typingctx, fn, m, d, jacp, jacr, point, body):  # type: ignore[no-untyped-def]
    """fn(m, d, jacp, jacr, point, body): mj_jac."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        _jump(builder, args[0], list(args[1:]), "pppppi")
        return context.get_dummy_value()
    return types.none(*([types.int64] * 7)), codegen


@intrinsic
def call_mdppi(typingctx, fn, m, d, a, b, n):  # type: ignore[no-untyped-def]
    """fn(m, d, a, b, n): mj_jacSite (jacp, jacr, site) and mj_solveM (x, y, n)."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        _jump(builder, args[0], list(args[1:]), "ppppi")
        return context.get_dummy_value()
    return types.none(*([types.int64] * 6)), codegen


@intrinsic
def call_object_velocity(typingctx, fn, m, d, objtype, objid, res, flg_local):  # type: ignore[no-untyped-def]
    """fn(m, d, objtype, objid, res, flg_local): mj_objectVelocity."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        _jump(builder, args[0], list(args[1:]), "ppiipi")
        return context.get_dummy_value()
    return types.none(*([types.int64] * 7)), codegen


@intrinsic
def call_integrate_pos(typingctx, fn, m, qpos, qvel, dt):  # type: ignore[no-untyped-def]
    """fn(m, qpos, qvel, dt): mj_integratePos."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        _jump(builder, args[0], list(args[1:]), "pppd")
        return context.get_dummy_value()
    return types.none(types.int64, types.int64, types.int64, types.int64, types.float64), codegen


def _load(builder: ir.IRBuilder, address: ir.Value, kind: ir.Type) -> ir.Value:
    return builder.load(builder.inttoptr(address, kind.as_pointer()))


@intrinsic
def load_i32(typingctx, address):  # type: ignore[no-untyped-def]
    """The C int at ``address`` (e.g. mjData.ncon at its controllers.mujoco_layout offset)."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.sext(_load(builder, args[0], _I32), _I64)
    return types.int64(types.int64), codegen


@intrinsic
def load_pointer(typingctx, address):  # type: ignore[no-untyped-def]
    """The pointer at ``address``, as an int64 (e.g. mjData.contact)."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return _load(builder, args[0], _I64)
    return types.int64(types.int64), codegen



@intrinsic
def int32_pointer(typingctx, address):  # type: ignore[no-untyped-def]
    """``address`` as an int32* (for numba.carray over a C array, e.g. mjData.contact read as ints)."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.inttoptr(args[0], _I32.as_pointer())
    return types.CPointer(types.int32)(types.int64), codegen


@intrinsic
def float64_pointer(typingctx, address):  # type: ignore[no-untyped-def]
    """``address`` as a double* (for numba.carray over a C array, e.g. mjData.efc_force)."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.inttoptr(args[0], _F64.as_pointer())
    return types.CPointer(types.float64)(types.int64), codegen
