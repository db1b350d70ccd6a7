#!/usr/bin/env python3
"""B-mode frames of a label volume from an INDEPENDENT simulator, MUST's Python port pymust
(D. Garcia, https://www.biomecardio.org/MUST), not sonoslice's own `simulate`.

  build/venv/bin/python examples/independent_bmode.py --labels labels.nii --tissues tissues.json
      --poses poses.npy --out frames.npy [--probe FANSLICER.json] [--downsampling 2] [--seed 0]
      [--threads 2] [--frequency 5] [--elements 64] [--specular 0.4] [--png sheet.png]

Output: (N, H, W) uint8 on the probe's pixel grid (default W1, fan-slicer's LUS config at
downsampling 2: 334 x 272 px of 0.247 mm), 0 outside the fan, for probe->world poses (N, 4, 4),
mm, LPS, read as sonoslice's Slicer reads them.

Simulator: pymust.simus in 2-D (the image plane: no elevation beam or slice thickness); a convex
array of the probe's radius whose element normals span its sector (64 elements, 5 MHz, C5-2v's
79 % bandwidth); one transmit a frame with all delays 0, a wave diverging from the beams' apex;
pymust.rf2iq, pymust.dasmtx (its f-number, plus a Hann weight on each element's angle) on a
256-beam polar grid, pymust.bmode (50 dB), bilinear scan conversion.
Scatter map: pymust.genscat positions (~30k in W1's fan), each with the label of its nearest
voxel (probe point (x, y, 0) -> world by the pose -> voxel by the volume's origin, spacing and
direction) and amplitude scatter_mean * N(0, 1) (thinned where scatter_density < 10). Along ~530
rays from the apex (0.1 mm steps): attenuation is MUST's own 0.5 dB/cm/MHz (frequency dependent)
plus each tissue's excess over it at fc, two-way; every label change is a specular point per ray
(--specular * R per wavelength of interface, R from impedance_mrayl, times |cos| of the incidence
angle) and weights everything beyond it by the two-way transmission 1 - R^2. So air and lung
shadow completely, bone (7.8 MRayl, 20 dB/cm/MHz) within a millimetre, and a face in air sees
nothing. Not modelled: reverberation and other multiple scattering, refraction, sound-speed
changes (1540 m/s), nonlinearity, noise. With one unfocused transmit, clutter from lit tissue
fills shadows at about -15 to -25 dB (dark grey, not black); speckle is stretched laterally.
A fixed TGC undoes MUST's 0.5 dB/cm/MHz and the 2-D spreading; the gain puts each frame's median
insonified echo 28 dB below white.

Time: 6-8 s a W1 frame on this 2-core machine, ~95 % of it in pymust.simus; the first frame also
builds the DAS matrix (~2 s). Progress goes to stderr.
Needs `pip install "pymust<0.1.9"` where numpy is 1.x (Debian's 1.24): 0.1.9 calls numpy 2's np.concat.
"""
import os

# pymust's per-frequency products are small; a multi-threaded BLAS makes them ~15x slower.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from multiprocessing.pool import ThreadPool  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse  # noqa: E402
from scipy import ndimage  # noqa: E402

import pymust  # noqa: E402
import sonoslice  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
W1 = os.path.join(ROOT, "data", "fanslicer", "models_intensity_LUS_config.json")
C = 1540.0                 # m/s, MUST's default and ours
ALPHA0 = 0.5               # dB/cm/MHz handed to MUST for every tissue
Z_COUPLING = 1.54          # MRayl, the lens/gel in front of the elements
MARGIN = np.deg2rad(3.0)   # scatterers a little beyond the sector: the edge beams see them
DR_DB = 50.0               # log-compression range
SPECKLE_DB = 28.0          # median echo this far below white


class Geometry:
    """The fan in the probe frame (mm): beams from an apex at (0, face_y - R), radii R..rmax."""

    def __init__(self, probe):
        j = json.loads(probe.to_json())
        if j.get("type") != "curvilinear":
            raise ValueError(f"probe type {j.get('type')!r}: only curvilinear probes are handled")
        self.R, self.rmax = j["radius_mm"], j["radius_mm"] + j["depth_mm"]
        self.half, self.apex_y = np.deg2rad(j["sector_deg"]) / 2, j["face_y_mm"] - j["radius_mm"]
        im = j["image"]
        self.W, self.H = im["width"], im["height"]
        self.origin, self.spacing = im["origin_mm"], im["spacing_mm"]
        self.mask = np.asarray(probe.mask).astype(bool)


def make_param(geo, fc_mhz, n_el):
    """A convex array whose element normals span the sector, on the probe's radius (m)."""
    param = pymust.getparam("C5-2v")                   # keeps its bandwidth and kerf ratio
    R = geo.R * 1e-3
    param.fc, param.radius, param.Nelements = fc_mhz * 1e6, R, n_el
    # getElementPositions puts the outer normals at +-(N-1)*asin(pitch/2R): make that the half sector
    param.pitch = 2 * R * np.sin(geo.half / (n_el - 1))
    param.kerf, param.width = 0.094 * param.pitch, 0.906 * param.pitch
    param.attenuation, param.c, param.fs = ALPHA0, C, 4 * param.fc
    param.h = float(param.getElementPositions()[3].ravel()[0])  # apothem: apex at z = -h
    return param


def ray_labels(labels, vol, pose, geo, th, r):
    """Nearest-voxel labels at the polar points (th, r) about the apex; 0 (air) outside the volume."""
    T, Rr = np.meshgrid(th, r, indexing="ij")
    pts = np.stack([Rr * np.sin(T), geo.apex_y + Rr * np.cos(T), 0 * T, 1 + 0 * T], -1)
    world = (pts.reshape(-1, 4) @ pose.T)[:, :3]
    D, o, s = np.asarray(vol.direction), np.asarray(vol.origin), np.asarray(vol.spacing)
    ijk = np.rint((world - o) @ D / s).astype(np.int64)      # D^T (p - o) / spacing
    inside = np.all((ijk >= 0) & (ijk < labels.shape[::-1]), axis=1)
    out = np.zeros(len(ijk), dtype=np.int64)
    i, j, k = ijk[inside].T
    out[inside] = labels[k, j, i]                            # the array is (z, y, x)
    return out.reshape(T.shape)


def scatterers(lab, table, param, th, r, spec_gain, rng):
    """Scatterers (MUST x, z in m), their reflection coefficients, and the two-way transmission
    on the rays (th, r) about the apex (lab: their labels)."""
    Z, att, mean, dens = (table[k][lab] for k in ("impedance_mrayl", "attenuation_db_cm_mhz",
                                                 "scatter_mean", "scatter_density"))
    dth, dr, lam = th[1] - th[0], r[1] - r[0], C / param.fc * 1e3
    Zc = np.concatenate([np.full((len(th), 1), Z_COUPLING), Z], axis=1)
    refl = (Zc[:, 1:] - Zc[:, :-1]) / (Zc[:, 1:] + Zc[:, :-1])   # R at the front of sample j
    step = (1 - refl ** 2) * 10 ** (-2 * (att - ALPHA0) * param.fc / 1e6 * dr / 10 / 20)
    trans = np.cumprod(step, axis=1)                 # two-way amplitude reaching sample j
    # Speckle: MUST's own pseudorandom distribution over the fan's bounding box.
    h, rmax, a = param.h, (r[-1] + 0.5) * 1e-3, -th[0]
    zmin = r[0] * 1e-3 * np.cos(a) - h
    xs, _, zs = pymust.genscat(np.array([2 * rmax * np.sin(a), rmax - h - zmin]), param)[:3]
    zs = zs + zmin
    i = np.rint((np.arctan2(xs, zs + h) - th[0]) / dth).astype(int)
    j = np.rint((np.hypot(xs, zs + h) * 1e3 - r[0]) / dr).astype(int)
    # None in the first mm: MUST's far-field element model does not hold there.
    keep = (i >= 0) & (i < len(th)) & (r[np.clip(j, 0, len(r) - 1)] > r[0] + 1) & (j < len(r))
    xs, zs, i, j = xs[keep], zs[keep], i[keep], j[keep]
    p = np.minimum(1.0, dens[i, j] / 10)             # fewer than 10 per cell: thin, keep power
    rc = mean[i, j] * trans[i, j] * rng.standard_normal(len(i)) / np.sqrt(p)
    sel = (rng.random(len(i)) < p) & (trans[i, j] > 1e-3) & (rc != 0)   # < -60 dB: skip the work
    # Specular: a point where a ray changes label, amplitude spec_gain * R per wavelength of
    # interface (points are r*dth apart). The label boundary is a voxel staircase, whose steps
    # would break the interface's coherence: the point goes where the smoothed log-impedance
    # crosses the mean of the two sides (<= 1 mm away), and is weighted by |cos| of the
    # incidence angle from that smoothed field's gradient, so faces seen edge-on stay dim.
    lnz = ndimage.gaussian_filter(np.log(Z), (0.8 / (r.mean() * dth), 0.8 / dr))
    gt, gr = np.gradient(lnz, dth, dr)
    ii, jj = np.nonzero(refl[:, 1:])
    jj, n, W = jj + 1, np.arange(len(ii)), 10
    win = np.clip(jj[:, None] + np.arange(-W, W + 1), 0, len(r) - 1)
    v = lnz[ii[:, None], win] - (np.log(Z[ii, jj - 1]) + np.log(Z[ii, jj]))[:, None] / 2
    cross = (v[:, :-1] * v[:, 1:] <= 0) & (v[:, :-1] != v[:, 1:])
    k = np.argmin(np.where(cross, np.abs(np.arange(-W, W) + 0.5), np.inf), axis=1)
    frac = v[n, k] / np.where(cross[n, k], v[n, k] - v[n, k + 1], 1)
    pos = np.where(cross[n, k], r[win[n, k]] + frac * dr, r[jj] - dr / 2)
    jp = np.clip(np.rint((pos - r[0]) / dr).astype(int), 0, len(r) - 1)
    cos = np.abs(gr[ii, jp]) / (np.hypot(gr[ii, jp], gt[ii, jp] / r[jp]) + 1e-12)
    rcs = spec_gain * refl[ii, jj] * cos * trans[ii, jj - 1] * r[jj] * dth / lam
    ok = np.abs(rcs) > 1e-6
    rsp, tsp = pos[ok] * 1e-3, th[ii[ok]]
    x, z = np.concatenate([xs[sel], rsp * np.sin(tsp)]), np.concatenate([zs[sel], rsp * np.cos(tsp) - h])
    return x, z, np.concatenate([rc[sel], rcs[ok]]), trans, int(sel.sum()), int(ok.sum())


def simulate_rf(x, z, rc, param, geo, pool, chunk=2000):
    """pymust.simus in chunks (cache-sized), summed. Two silent (RC = 0) scatterers at the far
    corners give every chunk the same maximum distance, hence the same RF length and time axis."""
    rf, a = (geo.rmax + 1.5) * 1e-3, geo.half + MARGIN
    far_x, far_z = np.array([-1, 1]) * rf * np.sin(a), np.full(2, rf * np.cos(a) - param.h)
    opt = pymust.utils.Options()
    opt.dBThresh, opt.WaitBar = -60, False   # spectra kept down to -60 dB (simus: -100)
    # One segment per element (MUST would split each 1.9-wavelength element in two): 3.5x faster;
    # the far-field approximation then holds beyond ~w^2/lambda = 1 mm from the array.
    opt.ElementSplitting = 1
    dels = np.zeros((1, param.Nelements))

    def one(s):
        xx, zz, cc = (np.concatenate([v[s], w])[None] for v, w in ((x, far_x), (z, far_z), (rc, [0, 0])))
        return pymust.simus(xx, zz, cc, dels, param.copy(), opt)[0]

    parts = pool.map(one, [slice(k, k + chunk) for k in range(0, max(len(x), 1), chunk)])
    n = max(p.shape[0] for p in parts)
    return sum(np.pad(p, ((0, n - p.shape[0]), (0, 0))) for p in parts)


class Imager:
    """Receive: DAS onto a polar grid, TGC, log compression, scan conversion to the probe's pixels."""

    def __init__(self, geo, param, th_rays, r_rays, n_beams=256):
        self.geo, self.param = geo, param
        lam = C / param.fc * 1e3
        self.th = np.linspace(-geo.half, geo.half, n_beams)
        self.r = np.arange(geo.R + 0.2, geo.rmax + lam / 2, lam / 2)   # mm from the apex
        T, Rr = np.meshgrid(self.th, self.r)                            # (n_r, n_beams)
        self.x, self.z = Rr * np.sin(T) * 1e-3, Rr * np.cos(T) * 1e-3 - param.h
        self.M, self.nl = None, -1
        # The label rays nearest to each beamformed point (to find the insonified ones).
        self.ray_ij = (np.rint((T - th_rays[0]) / (th_rays[1] - th_rays[0])).astype(int),
                       np.rint((Rr - r_rays[0]) / (r_rays[1] - r_rays[0])).astype(int))
        # TGC: undo the 2-D spreading (1/sqrt(r) each way) and MUST's ALPHA0, two-way, as the
        # pulse-echo spectrum feels it (its low frequencies go further than fc's would).
        f = np.linspace(0, 2 * param.fc, 2001)[1:]
        S2 = np.abs(param.getPulseSpectrumFunction()(2 * np.pi * f)
                    * param.getProbeFunction()(2 * np.pi * f) ** 2) ** 2
        np_per_mm = ALPHA0 / 8.686 * f / 1e6 / 10                 # amplitude, one way
        loss = np.sqrt((S2 * np.exp(-4 * np.outer(self.r - geo.R, np_per_mm))).sum(1) / S2.sum())
        self.gain = (self.r / geo.R / loss)[:, None]
        # Scan conversion: each pixel's (theta, r) as fractional polar indices.
        u, v = np.meshgrid(np.arange(geo.W), np.arange(geo.H))
        px = geo.origin[0] + u * geo.spacing[0]
        py = geo.origin[1] + v * geo.spacing[1] - geo.apex_y
        self.coords = np.stack([(np.hypot(px, py) - self.r[0]) / (self.r[1] - self.r[0]),
                                (np.arctan2(px, py) - self.th[0]) / (self.th[1] - self.th[0])])

    def das_matrix(self, shape):
        p = self.param.copy()
        p.fnumber = None                         # dasmtx picks it from the element directivity
        M = pymust.dasmtx(1j * np.array(shape), self.x, self.z, np.zeros((1, p.Nelements)), p)
        # dasmtx sums its aperture uniformly (-13 dB sidelobes, which smear bright interfaces
        # over the shadows below them): weight each element by a Hann window of its angle.
        xe, ze, the, _ = (a.ravel() for a in p.getElementPositions())
        e, k = M.col // shape[0], M.row
        dx, dz = self.x.ravel(order="F")[k] - xe[e], self.z.ravel(order="F")[k] - ze[e]
        phi = (np.arcsin(dx / np.hypot(dx, dz)) - the[e]) / np.arctan(1 / 2 / p.fnumber)
        M.data *= np.cos(np.pi / 2 * np.clip(phi, -1, 1)) ** 2
        M = M.tocsr()
        # The aperture grows with depth (fixed f-number): divide each point by the sum of its
        # weights (a point echo then comes out the same with any aperture).
        norm = np.asarray(abs(M).sum(axis=1)).ravel()
        return scipy.sparse.diags(1 / np.maximum(norm, 1e-12 * norm.max())) @ M

    def __call__(self, rf, trans):
        if rf.shape[0] != self.nl:
            self.M, self.nl = self.das_matrix(rf.shape), rf.shape[0]
        iq = pymust.rf2iq(rf, self.param.copy())
        bf = (self.M @ iq.flatten(order="F")).reshape(self.x.shape, order="F") * self.gain
        env = np.abs(bf)
        # Gain: the median echo of the insonified points sits SPECKLE_DB below white (a
        # scanner's auto-gain); brighter echoes (interfaces) saturate.
        lit = trans[self.ray_ij] > 1e-3
        if not lit.any() or not env[lit].max() > 0:
            return np.zeros((self.geo.H, self.geo.W), np.uint8)
        white = max(np.median(env[lit]) * 10 ** (SPECKLE_DB / 20), env[lit].max() * 1e-3)
        bf = bf * np.minimum(1, white / np.maximum(env, 1e-30))
        # pymust.bmode scales by the maximum: a last sample at `white` pins it.
        with np.errstate(divide="ignore"):   # exact zeros (shadows) -> -inf dB -> black
            polar = pymust.bmode(np.append(bf.ravel(), white + 0j), DR_DB)[:-1].reshape(bf.shape)
        img = ndimage.map_coordinates(polar.astype(np.float32), self.coords, order=1, mode="nearest")
        return np.where(self.geo.mask, np.clip(np.rint(img), 0, 255), 0).astype(np.uint8)


def contact_sheet(path, frames, label_slices, mask):
    """Row 1: the frames; row 2: the frames with sonoslice's label boundaries in red; row 3: labels."""
    from PIL import Image
    lab = label_slices.astype(np.uint16)
    edge = np.zeros(lab.shape, bool)
    edge[:, :, 1:] |= lab[:, :, 1:] != lab[:, :, :-1]
    edge[:, 1:, :] |= lab[:, 1:, :] != lab[:, :-1, :]
    grey = np.repeat(frames[..., None], 3, -1)
    over = grey.copy()
    over[edge & mask] = (255, 0, 0)
    pad = ((0, 6), (0, 6), (0, 0))   # white gaps between the tiles
    rows = [np.concatenate([np.pad(im, pad, constant_values=255) for im in row], 1)
            for row in (grey, over, sonoslice.colorize(lab, mask))]
    Image.fromarray(np.concatenate(rows, 0)).save(path)


def read_inputs(args):
    for f in (args.labels, args.tissues, args.poses, args.probe):
        if not os.path.isfile(f):
            raise ValueError(f"no such file: {f}")
    for f in filter(None, (args.out, args.png)):
        if not os.path.isdir(os.path.dirname(os.path.abspath(f))):
            raise ValueError(f"{f}: its folder does not exist")
    try:
        poses = np.asarray(np.load(args.poses), dtype=np.float64)
    except (ValueError, OSError):
        raise ValueError(f"{args.poses}: not a numeric .npy array") from None
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not len(poses) or not np.isfinite(poses).all():
        raise ValueError(f"{args.poses}: poses must be finite (N, 4, 4) matrices, got {poses.shape}")
    vol = sonoslice.Volume.from_file(args.labels)
    labels = np.asarray(vol.array)
    if not np.issubdtype(labels.dtype, np.integer):           # e.g. a float NIfTI of labels
        if not np.array_equal(labels, np.rint(labels)):
            raise ValueError(f"{args.labels}: not a label volume (non-integer values)")
        labels = labels.astype(np.int32)
    if labels.min() < 0:
        raise ValueError(f"{args.labels}: negative labels")
    keys = ("impedance_mrayl", "attenuation_db_cm_mhz", "scatter_mean", "scatter_density")
    try:
        with open(args.tissues) as f:
            rows = json.load(f)["tissues"]
        n = int(max(labels.max(), max(t["label"] for t in rows))) + 1
        table = {k: np.full(n, np.nan) for k in keys}
        for t in rows:
            for k in keys:
                table[k][int(t["label"])] = float(t.get(k, 10.0) if k == "scatter_density" else t[k])
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{args.tissues}: not a tissue table ({type(e).__name__}: {e})") from None
    present = set(np.nonzero(np.bincount(labels.ravel(), minlength=n))[0]) | {0}   # 0: outside
    missing = sorted(int(k) for k in present if np.isnan(table["impedance_mrayl"][k]))
    if missing:
        raise ValueError(f"{args.tissues}: no row for label(s) {missing}")
    probe = sonoslice.Probe.from_fanslicer(args.probe, downsampling=args.downsampling)
    return vol, labels, table, poses, probe


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for name in ("--labels", "--tissues", "--poses", "--out"):
        ap.add_argument(name, required=True)
    ap.add_argument("--probe", default=W1, help="fan-slicer config (default: W1's)")
    ap.add_argument("--downsampling", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--frequency", type=float, default=5.0, help="MHz")
    ap.add_argument("--elements", type=int, default=64)
    ap.add_argument("--specular", type=float, default=0.4,
                    help="interface echo per wavelength of interface, in units of R (0: none)")
    ap.add_argument("--png", help="contact sheet of up to 6 frames")
    args = ap.parse_args()
    try:
        if not (0.5 <= args.frequency <= 30 and 8 <= args.elements <= 512 and args.threads >= 1):
            raise ValueError("--frequency must be 0.5-30 MHz, --elements 8-512, --threads >= 1")
        vol, labels, table, poses, probe = read_inputs(args)
        geo = Geometry(probe)
    except Exception as e:                       # bad input: one line, exit 1
        print(f"independent_bmode: {e}", file=sys.stderr)
        sys.exit(1)

    param = make_param(geo, args.frequency, args.elements)
    # Rays for the label map: <= lambda/2 apart at the deepest point (the specular points on
    # them must add coherently along an interface), 0.1 mm steps.
    n_rays = int(np.ceil(geo.rmax * 2 * (geo.half + MARGIN) / (C / param.fc * 1e3 / 2))) + 1
    th = np.linspace(-geo.half - MARGIN, geo.half + MARGIN, n_rays)
    r = np.arange(geo.R, geo.rmax + 1.0, 0.1)
    imager = Imager(geo, param, th, r)
    frames = np.zeros((len(poses), geo.H, geo.W), np.uint8)
    with ThreadPool(args.threads) as pool:
        for n, pose in enumerate(poses):
            t0 = time.time()
            np.random.seed((args.seed * 1000003 + n) % 2**32)       # genscat draws from np.random
            rng = np.random.default_rng([args.seed, n])
            lab = ray_labels(labels, vol, pose, geo, th, r)
            x, z, rc, trans, ns, nsp = scatterers(lab, table, param, th, r, args.specular, rng)
            if len(x):                               # else nothing is insonified: black
                frames[n] = imager(simulate_rf(x, z, rc, param, geo, pool), trans)
            print(f"frame {n + 1}/{len(poses)}: {ns} scatterers + {nsp} interface points, "
                  f"{time.time() - t0:.1f} s", file=sys.stderr, flush=True)
    np.save(args.out, frames)
    print(f"wrote {args.out} {frames.shape}", file=sys.stderr)
    if args.png:
        k = min(6, len(poses))
        slicer = sonoslice.Slicer(vol, probe, interpolation="nearest", fill=0)
        contact_sheet(args.png, frames[:k], np.asarray(slicer.slice(poses[:k])), geo.mask)
        print(f"wrote {args.png}", file=sys.stderr)


if __name__ == "__main__":
    main()
