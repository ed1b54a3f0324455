"""Every convention bakery uses, written once.

All other modules import from here; every store records :func:`convention_attributes` at its root.

================================  ===========================================================================
Convention                        Value
================================  ===========================================================================
Bake frame                        Right-handed, +Y up. Directions are unit 3-vectors (x, y, z) in this frame.
SH basis                          Real, orthonormal over the sphere, Condon–Shortley phase as in the ZH3 paper
                                  (seed 001, Eq. 4–5): Y1,-1 = -c·y, Y1,0 = c·z, Y1,1 = -c·x, c = sqrt(3/4π).
SH index                          k = l·(l+1) + m, m ∈ [-l, l]; arrays are (..., (L+1)², channels).
SH content                        Stored SH coefficients are of **radiance**. Irradiance is the cosine-lobe
                                  convolution applied at evaluation: band factors A_l (π, 2π/3, π/4, 0, -π/24 …).
Irradiance                        E(n) = ∫ L(ω) max(0, n·ω) dω (not divided by π): constant L = c gives E = πc.
Radiance units                    Those of the input (scene-linear, as read); no exposure applied by default.
Colour                            Linear Rec.709/sRGB primaries; luminance weights (0.2126, 0.7152, 0.0722).
Cube face order                   +X, -X, +Y, -Y, +Z, -Z (faces 0–5).
Cube face orientation             OpenGL / D3D / KTX cube maps: texel (row i, column j) of a face of size N has
                                  s = (j+½)/N, t = (i+½)/N, u = 2s-1, v = 2t-1 and direction ∝
                                  +X:(1,-v,-u)  -X:(-1,-v,u)  +Y:(u,1,v)  -Y:(u,-1,-v)  +Z:(u,-v,1)  -Z:(-u,-v,-1).
Equirect (latlong) orientation    OpenEXR / USD DomeLight: row 0 = zenith (+Y), column 0 = longitude +π; a
                                  direction with longitude φ = atan2(x, z) and latitude asin(y) sits at
                                  s = ½ - φ/2π, t = ½ - latitude/π. The image centre looks down +Z.
Angular map (Debevec)             u, v ∈ [-1, 1] (v up), r = √(u²+v²) ≤ 1; direction = (u·sin(πr)/r, v·sin(πr)/r,
                                  cos(πr)): the disc centre is +Z, the rim is -Z. Texels outside the disc are masked.
Mirrored ball (UsdLux)            The disc of the angular map with θ = 2·asin r: direction = (2u√(1-r²),
                                  2v√(1-r²), 1-2r²), the view ray -Z reflected about the ball's normal.
Vertical cross (UsdLux)           3N × 4N: +Y above the middle row +X | +Z | -X, then -Y and -Z (upside down);
                                  within a face a = 2s-1 rightwards, b = 2t-1 downwards: +Y:(-a,1,b)
                                  +X:(1,-b,a)  +Z:(-a,-b,1)  -X:(-1,-b,-a)  -Y:(-a,-1,-b)  -Z:(-a,b,-1). The
                                  centre face continues the latlong's centre; empty cells are masked.
Roughness                         Every stored roughness is GGX α unless its name says ``perceptual``; α = r².
================================  ===========================================================================
"""

from __future__ import annotations

import json

import numpy as np

#: Rec.709 luminance weights for linear RGB.
LUMINANCE_WEIGHTS = np.array([0.2126, 0.7152, 0.0722])
#: A probe whose capture rays see the back of single-sided surfaces this often or more is inside geometry
#: (Majercik et al. 2021, "Scaling Probe-Based Real-Time Dynamic Global Illumination for Production", Sec. 4);
#: stores record it as ``inside_geometry_backface_fraction``.
INSIDE_BACKFACE_FRACTION = 0.25

#: The table above as data, recorded in every store (root attribute ``conventions``, a JSON object).
CONVENTIONS: dict[str, str] = {
    "frame": "right-handed, +Y up",
    "sh_basis": "real orthonormal, Condon-Shortley phase: Y1,-1=-c*y, Y1,0=c*z, Y1,1=-c*x (ZH3 paper Eq. 4-5)",
    "sh_index": "k = l*(l+1) + m",
    "sh_content": "radiance coefficients; irradiance = cosine-lobe convolution A_l at evaluation",
    "irradiance": "E(n) = integral L(w) max(0, n.w) dw (not divided by pi)",
    "radiance_units": "as input, scene-linear",
    "colour": "linear Rec.709 RGB; luminance = 0.2126 R + 0.7152 G + 0.0722 B",
    "cube_face_order": "+X,-X,+Y,-Y,+Z,-Z",
    "cube_face_orientation": "OpenGL/D3D/KTX: u=2s-1, v=2t-1 (t down rows); +X:(1,-v,-u) -X:(-1,-v,u) "
    "+Y:(u,1,v) -Y:(u,-1,-v) +Z:(u,-v,1) -Z:(-u,-v,-1)",
    "equirect_orientation": "row 0 = +Y (zenith), column 0 = longitude +pi, longitude = atan2(x, z), "
    "image centre = +Z (OpenEXR / USD DomeLight)",
    "angular_map": "Debevec: centre = +Z, rim = -Z, direction = (u sin(pi r)/r, v sin(pi r)/r, cos(pi r)), v up",
    "mirrored_ball": "UsdLux mirroredBall: disc as angular_map, theta = 2 asin(r), "
    "direction = (2u sqrt(1-r^2), 2v sqrt(1-r^2), 1-2r^2) (view ray -Z reflected about (u, v, sqrt(1-r^2)))",
    "vertical_cross": "UsdLux cubeMapVerticalCross, 3N x 4N: +Y above, +X|+Z|-X, then -Y, -Z; a right, b down in "
    "[-1,1]: +Y:(-a,1,b) +X:(1,-b,a) +Z:(-a,-b,1) -X:(-1,-b,-a) -Y:(-a,-1,-b) -Z:(-a,b,-1)",
    "roughness": "GGX alpha unless named perceptual; alpha = perceptual^2",
}


def stage_to_bake_axes(up_axis: str) -> np.ndarray:
    """(3, 3) stage axes → bake frame for row vectors (bake = stage @ M): a ``Z``-up stage's (x, y, z) is the bake
    frame's (x, z, −y); a ``Y``-up stage's is unchanged."""
    if up_axis == "Z":
        return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    return np.eye(3)


def convention_attributes() -> dict[str, str]:
    """The conventions as one JSON string plus one attribute per entry, for a store's root."""
    attributes = {f"convention.{key}": value for key, value in CONVENTIONS.items()}
    attributes["conventions"] = json.dumps(CONVENTIONS, sort_keys=True)
    return attributes


#: Capture seeds a store can record (its ``capture_seed`` attribute is an HDF5 int64).
SEED_RANGE = (-(1 << 63), (1 << 63) - 1)

#: Largest cube face size (texels) of a bake grid and of a probe's ``bakery:capture:resolution``.
MAX_FACE_SIZE = 4096
