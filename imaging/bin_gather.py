"""The float32 kernel's gather of 16 pixels' neighbouring bins as vector permutes over a register window.

A block's 16 consecutive pixels are a 4 x 4 sub-patch (``imaging.patches.patch_order`` with
``sub_patch=4``), whose bins lie close together: about 10-12 apart at most on the benchmark grid. Where
they span at most 14 bins, the 16 complex64 bins from the group's lowest index on (two 512-bit registers
of float32) hold every pixel's bin a and the next one, b; four two-register permutes
(``vpermi2ps``, LLVM's ``llvm.x86.avx512.vpermi2var.ps.512``: LLVM's ``shufflevector`` takes no variable
mask) take each lane's a.re, a.im, b.re and b.im out of them, already de-interleaved, into four planar
float32 rows. The scalar gather does two 8-byte loads and four 4-byte stores per pixel instead; a group
whose bins span more (or a CPU without AVX-512) takes it.

The values are the same bit for bit either way: only loads and permutes, no arithmetic on them.
"""

from __future__ import annotations

from imaging.numba_target import compiles_for_avx512, prefer_full_width_vectors

prefer_full_width_vectors()  # before numba builds its target (imaging/numba_target.py)

import numba  # noqa: E402
import numpy as np  # noqa: E402
from llvmlite import ir  # noqa: E402
from numba import types  # noqa: E402
from numba.core import cgutils  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

#: Pixels per permute gather: one 512-bit register of float32 lanes.
LANES = 16
#: Largest (max - min) of a group's bin indices the window holds: bins min .. min + 15, b being the next bin.
WINDOW_SPAN = LANES - 2
#: Whether the kernels compile the permute gather (numba's target has AVX-512): decided once, at import,
#: so each compiled kernel holds one path only.
PERMUTE_GATHER = compiles_for_avx512()


def _declare(module: ir.Module, name: str, ret: ir.Type, args: list[ir.Type]) -> ir.Function:
    """The LLVM intrinsic ``name`` in ``module`` (declared once per module)."""
    fn = module.globals.get(name)
    if fn is None:
        fn = ir.Function(module, ir.FunctionType(ret, args), name=name)
    return fn


@intrinsic
def window_gather16(typingctx, row, idx, i0, planar):
    """Pixels i0 .. i0 + 15's bins a = row[idx[i]] and b = row[idx[i] + 1] into planar[:, i] (a.re, a.im, b.re,
    b.im) by permutes over the window of 16 bins from min(idx[i0:i0 + 16], row.size - 16) on; True if done,
    False (nothing written) where the indices span more than WINDOW_SPAN bins or the row is shorter than
    16 bins. ``row`` is complex64, contiguous; ``idx`` uint32 with idx + 1 inside the row; ``planar``
    float32 [4, n], contiguous; the caller keeps i0 + 16 <= n. Needs AVX-512 (``PERMUTE_GATHER``)."""
    if not (isinstance(row, types.Array) and row.dtype == types.complex64 and row.layout == "C" and row.ndim == 1
            and isinstance(idx, types.Array) and idx.dtype == types.uint32 and idx.layout == "C"
            and isinstance(planar, types.Array) and planar.dtype == types.float32 and planar.ndim == 2
            and planar.layout == "C" and isinstance(i0, types.Integer)):
        return None
    sig = types.boolean(row, idx, i0, planar)

    def codegen(context, builder, signature, args):
        row_v, idx_v, i0_v, planar_v = args
        row_a = context.make_array(signature.args[0])(context, builder, row_v)
        idx_a = context.make_array(signature.args[1])(context, builder, idx_v)
        out_a = context.make_array(signature.args[3])(context, builder, planar_v)
        module = builder.module
        i32, i64, f32 = ir.IntType(32), ir.IntType(64), ir.FloatType()
        v16i, v16f = ir.VectorType(i32, LANES), ir.VectorType(f32, LANES)
        umin = _declare(module, "llvm.vector.reduce.umin.v16i32", i32, [v16i])
        permute = _declare(module, "llvm.x86.avx512.vpermi2var.ps.512", v16f, [v16f, v16i, v16f])

        start = context.cast(builder, i0_v, signature.args[2], types.intp)
        lanes = builder.load(builder.bitcast(builder.gep(idx_a.data, [start]), v16i.as_pointer()), align=4)
        n_row = builder.extract_value(row_a.shape, 0)
        last = builder.trunc(builder.sub(n_row, ir.Constant(i64, LANES)), i32)  # the last window's first bin
        n_cols = builder.extract_value(out_a.shape, 1)

        def clamped(first):
            """The window from bin ``first`` on, moved back to end at the row's end where it would not."""
            return builder.select(builder.icmp_signed("<", first, last), first, last)

        def relative(base):
            """Each lane's bin from ``base`` on, and whether all lie within WINDOW_SPAN (negatives wrap)."""
            splat = builder.shuffle_vector(builder.insert_element(ir.Constant(v16i, ir.Undefined), base,
                                                                  ir.Constant(i32, 0)),
                                           ir.Constant(v16i, ir.Undefined), ir.Constant(v16i, [0] * LANES))
            rel = builder.sub(lanes, splat)
            inside = builder.icmp_unsigned("<=", rel, ir.Constant(v16i, [WINDOW_SPAN] * LANES))
            all_inside = builder.icmp_unsigned("==", builder.bitcast(inside, ir.IntType(LANES)),
                                               ir.Constant(ir.IntType(LANES), (1 << LANES) - 1))
            return rel, all_inside

        def permute_window(base, rel):
            floats = builder.bitcast(builder.gep(row_a.data, [builder.zext(base, i64)]), f32.as_pointer())
            w0 = builder.load(builder.bitcast(floats, v16f.as_pointer()), align=4)
            w1 = builder.load(builder.bitcast(builder.gep(floats, [ir.Constant(i64, LANES)]), v16f.as_pointer()), align=4)
            twice = builder.add(rel, rel)  # a's real part is float 2 rel of the window, its imaginary 2 rel + 1
            for n in range(4):
                lanes_out = builder.call(permute, [w0, builder.add(twice, ir.Constant(v16i, [n] * LANES)), w1])
                at = builder.add(builder.mul(ir.Constant(i64, n), n_cols), start)
                builder.store(lanes_out, builder.bitcast(builder.gep(out_a.data, [at]), v16f.as_pointer()), align=4)

        # First the window centred on the mean of the first and last pixels' bins (opposite corners of a
        # sub-patch): two scalar loads, no reduction. Where that misses a lane, the window from the lowest bin.
        corner = builder.load(builder.gep(idx_a.data, [builder.add(start, ir.Constant(i64, LANES - 1))]))
        first = builder.extract_element(lanes, ir.Constant(i32, 0))
        mid = builder.trunc(builder.lshr(builder.add(builder.zext(first, i64), builder.zext(corner, i64)),
                                         ir.Constant(i64, 1)), i32)
        centred = clamped(builder.select(builder.icmp_unsigned("<", mid, ir.Constant(i32, LANES // 2 - 1)),
                                         ir.Constant(i32, 0), builder.sub(mid, ir.Constant(i32, LANES // 2 - 1))))
        long_enough = builder.icmp_signed(">=", n_row, ir.Constant(i64, LANES))
        rel, inside = relative(centred)
        fits = cgutils.alloca_once(builder, ir.IntType(1))  # in the entry block: not one per call in a loop
        builder.store(builder.and_(long_enough, inside), fits)
        with builder.if_else(builder.load(fits), likely=True) as (then, otherwise):
            with then:
                permute_window(centred, rel)
            with otherwise:
                lowest = clamped(builder.call(umin, [lanes]))
                rel, inside = relative(lowest)
                builder.store(builder.and_(long_enough, inside), fits)
                with builder.if_then(builder.load(fits)):
                    permute_window(lowest, rel)
        fits = builder.load(fits)
        return fits

    return sig, codegen


@numba.njit(inline="always", fastmath=True)
def scalar_gather(row, idx, i_from, i_to, planar):
    """Pixels i_from .. i_to - 1's bins a = row[idx[i]] and b = row[idx[i] + 1] into planar[:, i]."""
    for i in range(i_from, i_to):
        j = idx[i]
        a = row[j]
        b = row[j + np.uint32(1)]
        planar[0, i] = a.real
        planar[1, i] = a.imag
        planar[2, i] = b.real
        planar[3, i] = b.imag


@numba.njit(inline="always", fastmath=True)
def gather_planar(row, idx, planar):
    """Every pixel's bins a = row[idx[i]] and b = row[idx[i] + 1] into planar [4, idx.size] float32 (a.re,
    a.im, b.re, b.im): by ``window_gather16`` for each group of 16 whose bins it holds where the CPU has
    AVX-512, else scalar. Returns the number of groups of 16 the permutes took."""
    nb = idx.size
    done = 0
    i0 = 0
    if PERMUTE_GATHER:
        while i0 + LANES <= nb:
            if window_gather16(row, idx, i0, planar):
                done += 1
            else:
                scalar_gather(row, idx, i0, i0 + LANES, planar)
            i0 += LANES
    scalar_gather(row, idx, i0, nb, planar)
    return done


@numba.njit(inline="always", fastmath=True)
def _gather_accumulate(row, idx, frac, cos_, sin_, v0, v1, acc_re, acc_im, linear):
    """The second and third passes of a (block, profile): gather the profile at idx (scalar loads and
    stores only: LLVM will not vectorise a gather here), then interpolate and accumulate value * exp(-j k dr)
    (vectorised)."""
    nb = idx.size
    if linear:
        for i in range(nb):
            j = idx[i]
            v0[i] = row[j]
            v1[i] = row[j + np.uint32(1)]
        for i in range(nb):
            t = frac[i]
            vr = v0[i].real + t * (v1[i].real - v0[i].real)
            vi = v0[i].imag + t * (v1[i].imag - v0[i].imag)
            acc_re[i] += vr * cos_[i] + vi * sin_[i]
            acc_im[i] += vi * cos_[i] - vr * sin_[i]
    else:
        for i in range(nb):
            v0[i] = row[idx[i]]
        for i in range(nb):
            vr = v0[i].real
            vi = v0[i].imag
            acc_re[i] += vr * cos_[i] + vi * sin_[i]
            acc_im[i] += vi * cos_[i] - vr * sin_[i]
