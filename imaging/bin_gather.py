"""The float32 kernel's gather of 16 (AVX-512) or 8 (AVX2) pixels' neighbouring bins as vector permutes over a
register window.

A block's 16 consecutive pixels are a 4 x 4 sub-patch (``imaging.patches.patch_order`` with
``sub_patch=4``), whose bins lie close together: about 6-7 apart at most on the benchmark grid, its 8-pixel
halves (4 x 2) 3-4. A group of LANES pixels (one vector register of float32 lanes) whose bins span at most
LANES - 2 is gathered out of the LANES complex64 bins from a window start on (two registers of float32),
which hold every pixel's bin a and the next one, b: four permutes take each lane's a.re, a.im, b.re and
b.im out of them, already de-interleaved, into four planar float32 rows. With AVX-512, 16 lanes, each a
two-register permute (``vpermi2ps``, LLVM's ``llvm.x86.avx512.vpermi2var.ps.512``: LLVM's ``shufflevector``
takes no variable mask); with AVX2 only, 8 lanes: the window's bins first split into a register of their
real parts and one of their imaginary parts (loaded as 128-bit quarters, two in-lane ``vshufps``), then each
row is one one-register permute (``vpermps``, ``llvm.x86.avx2.permps``) of one of them by the bin itself, a by
the lane's bin and b by the next (it replaced a permute of each window register and a blend per row, whose
masks took three compares). The scalar gather does two 8-byte loads and four 4-byte stores per pixel
instead; a group whose bins span more (or a CPU without AVX2) takes it. AVX2's hardware gathers (``vgatherdpd`` of the 8-byte pairs with
two shuffles per row, or ``vgatherdps`` of each planar row) made the kernel slower than the scalar gather on
Zen 3 (docs/benchmark-notes.md).

The values are the same bit for bit either way: only loads, shuffles and permutes, no arithmetic on them.
"""

from __future__ import annotations

from imaging.numba_target import compiles_for_avx2, compiles_for_avx512, prefer_full_width_vectors

prefer_full_width_vectors()  # before numba builds its target (imaging/numba_target.py)

import numba  # noqa: E402
import numpy as np  # noqa: E402
from llvmlite import ir  # noqa: E402
from numba import types  # noqa: E402
from numba.core import cgutils  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

#: Whether numba's target has AVX-512, and AVX2: decided once, at import, so each compiled kernel holds one
#: path only.
_AVX512, _AVX2 = compiles_for_avx512(), compiles_for_avx2()
#: Whether the kernels compile a permute gather (numba's target has AVX2, or AVX-512).
PERMUTE_GATHER = _AVX512 or _AVX2
#: Pixels per permute gather on this CPU: one register of float32 lanes (512 or 256 bits).
LANES = 16 if _AVX512 else 8
#: Largest (max - min) of a group's bin indices the window holds: bins min .. min + LANES - 1, b being the next bin.
WINDOW_SPAN = LANES - 2


def _declare(module: ir.Module, name: str, ret: ir.Type, args: list[ir.Type]) -> ir.Function:
    """The LLVM intrinsic ``name`` in ``module`` (declared once per module)."""
    fn = module.globals.get(name)
    if fn is None:
        fn = ir.Function(module, ir.FunctionType(ret, args), name=name)
    return fn


def _window_gather(lanes: int):
    """The permute gather of ``lanes`` (16: AVX-512, 8: AVX2) pixels as a numba intrinsic."""

    @intrinsic
    def window_gather(typingctx, row, idx, i0, planar):
        """Pixels i0 .. i0 + lanes - 1's bins a = row[idx[i]] and b = row[idx[i] + 1] into planar[:, i] (a.re,
        a.im, b.re, b.im) by permutes over the window of ``lanes`` bins from min(idx[i0:i0 + lanes], row.size -
        lanes) on; True if done, False (nothing written) where the indices span more than lanes - 2 bins or
        the row is shorter than the window. ``row`` is complex64, contiguous; ``idx`` uint32 with idx + 1
        inside the row; ``planar`` float32 [4, n], contiguous; the caller keeps i0 + lanes <= n. Needs
        AVX-512 for 16 lanes, AVX2 for 8."""
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
            vni, vnf = ir.VectorType(i32, lanes), ir.VectorType(f32, lanes)
            umin = _declare(module, f"llvm.vector.reduce.umin.v{lanes}i32", i32, [vni])
            if lanes == 16:
                permute2 = _declare(module, "llvm.x86.avx512.vpermi2var.ps.512", vnf, [vnf, vni, vnf])
            else:
                permute1 = _declare(module, "llvm.x86.avx2.permps", vnf, [vnf, vni])

            start = context.cast(builder, i0_v, signature.args[2], types.intp)
            lane_idx = builder.load(builder.bitcast(builder.gep(idx_a.data, [start]), vni.as_pointer()), align=4)
            n_row = builder.extract_value(row_a.shape, 0)
            last = builder.trunc(builder.sub(n_row, ir.Constant(i64, lanes)), i32)  # the last window's first bin
            n_cols = builder.extract_value(out_a.shape, 1)

            def clamped(first):
                """The window from bin ``first`` on, moved back to end at the row's end where it would not."""
                return builder.select(builder.icmp_signed("<", first, last), first, last)

            def relative(base):
                """Each lane's bin from ``base`` on, and whether all lie within the span (negatives wrap)."""
                splat = builder.shuffle_vector(builder.insert_element(ir.Constant(vni, ir.Undefined), base,
                                                                      ir.Constant(i32, 0)),
                                               ir.Constant(vni, ir.Undefined), ir.Constant(vni, [0] * lanes))
                rel = builder.sub(lane_idx, splat)
                inside = builder.icmp_unsigned("<=", rel, ir.Constant(vni, [lanes - 2] * lanes))
                all_inside = builder.icmp_unsigned("==", builder.bitcast(inside, ir.IntType(lanes)),
                                                   ir.Constant(ir.IntType(lanes), (1 << lanes) - 1))
                return rel, all_inside

            def permute_window(base, rel):
                floats = builder.bitcast(builder.gep(row_a.data, [builder.zext(base, i64)]), f32.as_pointer())
                if lanes == 16:
                    w0 = builder.load(builder.bitcast(floats, vnf.as_pointer()), align=4)
                    w1 = builder.load(builder.bitcast(builder.gep(floats, [ir.Constant(i64, lanes)]),
                                                      vnf.as_pointer()), align=4)
                    twice = builder.add(rel, rel)  # a's real part is float 2 rel of the window, its imaginary 2 rel + 1

                    def planar_row(n):
                        return builder.call(permute2, [w0, builder.add(twice, ir.Constant(vni, [n] * lanes)), w1])
                else:
                    # The window's 8 bins split once into their real and imaginary parts (two shuffles), so
                    # that each planar row is one permute of one register by the bin itself (a: rel, b: rel
                    # + 1, at most 7): no blend between two registers, and no mask to make for one.
                    # Loaded as bins 0, 1, 4, 5 and 2, 3, 6, 7 (128 bits each), an in-lane shuffle of the two
                    # gives each part in the bins' order, without a lane-crossing fix-up after it.
                    v4f = ir.VectorType(f32, 4)
                    quarters = [builder.load(builder.bitcast(builder.gep(floats, [ir.Constant(i64, 4 * q)]),
                                                             v4f.as_pointer()), align=4) for q in range(4)]
                    lo = builder.shuffle_vector(quarters[0], quarters[2], ir.Constant(vni, list(range(8))))
                    hi = builder.shuffle_vector(quarters[1], quarters[3], ir.Constant(vni, list(range(8))))
                    pairs = [0, 2, 8, 10, 4, 6, 12, 14]  # vshufps's in-lane pattern: a lane's evens of lo, then of hi
                    re = builder.shuffle_vector(lo, hi, ir.Constant(vni, pairs))
                    im = builder.shuffle_vector(lo, hi, ir.Constant(vni, [m + 1 for m in pairs]))
                    nxt = builder.add(rel, ir.Constant(vni, [1] * lanes))

                    def planar_row(n):
                        return builder.call(permute1, [(re, im)[n % 2], (rel, nxt)[n // 2]])
                for n in range(4):
                    lanes_out = planar_row(n)
                    at = builder.add(builder.mul(ir.Constant(i64, n), n_cols), start)
                    builder.store(lanes_out, builder.bitcast(builder.gep(out_a.data, [at]), vnf.as_pointer()), align=4)

            # First the window centred on the mean of the first and last pixels' bins (opposite corners of a
            # square or its half): two scalar loads, no reduction. Where that misses a lane, the window from
            # the lowest bin.
            corner = builder.load(builder.gep(idx_a.data, [builder.add(start, ir.Constant(i64, lanes - 1))]))
            first = builder.extract_element(lane_idx, ir.Constant(i32, 0))
            mid = builder.trunc(builder.lshr(builder.add(builder.zext(first, i64), builder.zext(corner, i64)),
                                             ir.Constant(i64, 1)), i32)
            centred = clamped(builder.select(builder.icmp_unsigned("<", mid, ir.Constant(i32, lanes // 2 - 1)),
                                             ir.Constant(i32, 0), builder.sub(mid, ir.Constant(i32, lanes // 2 - 1))))
            long_enough = builder.icmp_signed(">=", n_row, ir.Constant(i64, lanes))
            rel, inside = relative(centred)
            fits = cgutils.alloca_once(builder, ir.IntType(1))  # in the entry block: not one per call in a loop
            builder.store(builder.and_(long_enough, inside), fits)
            with builder.if_else(builder.load(fits), likely=True) as (then, otherwise):
                with then:
                    permute_window(centred, rel)
                with otherwise:
                    lowest = clamped(builder.call(umin, [lane_idx]))
                    rel, inside = relative(lowest)
                    builder.store(builder.and_(long_enough, inside), fits)
                    with builder.if_then(builder.load(fits)):
                        permute_window(lowest, rel)
            fits = builder.load(fits)
            return fits

        return sig, codegen

    return window_gather


#: The permute gathers of 16 pixels (AVX-512) and of 8 (AVX2); ``window_gather`` is this CPU's.
window_gather16 = _window_gather(16)
window_gather8 = _window_gather(8)
window_gather = window_gather16 if LANES == 16 else window_gather8


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
    a.im, b.re, b.im): by ``window_gather`` for each group of LANES whose bins it holds where the CPU has
    AVX2 or AVX-512, else scalar. Returns the number of groups of LANES the permutes took."""
    nb = idx.size
    done = 0
    i0 = 0
    if PERMUTE_GATHER:
        while i0 + LANES <= nb:
            if window_gather(row, idx, i0, planar):
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
