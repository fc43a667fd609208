"""Directional lightmaps from the final gather's radiance moments: L1 spherical harmonics per
texel (Godot 4's directional LightmapGI, Bakery's SH mode) and Unity's dominant-direction map.

Input per texel (any leading shape ``...``; the lead calls these per page, ``(H, W)``):

- ``irradiance`` E (..., 3), W/m^2: the final gather's irradiance for the texel's surface normal;
- ``l0`` (..., 3) = integral of L(w) dw and ``l1`` (..., 3, 3) [channel, axis] = integral of
  L(w) w dw over the texel's hemisphere (``Engine.gather`` with
  ``GatherOptions(directional=True)``: ``PointValues.l0``, ``PointValues.l1``), W/m^2;
- ``normals`` (..., 3), unit, the texel's surface normal in the same world frame.

The moments fix the first two bands of the radiance's real, orthonormal spherical harmonics
(Y00 = 1 / (2 sqrt(pi)), Y1m = sqrt(3 / (4 pi)) (y, z, x) for m = -1, 0, 1):

    c00 = Y00 l0,        c1m = sqrt(3 / (4 pi)) l1_(y, z, x),

and, convolved with the clamped cosine (Ramamoorthi and Hanrahan 2001, "An efficient
representation for irradiance environment maps": A0 = pi, A1 = 2 pi / 3), the irradiance they
give any unit normal n:

    E1(n) = pi Y00 c00 + (2 pi / 3) sum_m Y1m(n) c1m = l0 / 4 + n . l1 / 2.

E1 is the L1 truncation: for light from the hemisphere above n it is within l0 / 4 of the true
E(n) (|max(c, 0) - 1/4 - c/2| <= 1/4 for c = n . w), exact for a uniform hemisphere, and 3/4
of E for one direction along n. Every value written below is in the engines' lightmap unit,
E / pi (W/(m^2 sr): the radiance a white Lambertian surface reflects; an engine multiplies it
by the albedo), the unit of hirad's plain lightmaps (``outputs/lightmaps.py``). All are linear
in (E, l0, l1) except the normalised direction textures, which do not depend on the scale, so
an exposure or encoding (RGBM, dLDR, half float) applies to the colour layers alone.

Engine frames: ``to_engine`` is the 3x3 matrix taking hirad's world vectors to the engine's
world axes (for instance a Z-up right-handed scene into Godot's Y-up right-handed world, or
Unity's Y-up left-handed one, a reflection); it is applied to l1 and the normals. The default is
the identity (the caller converts).

Formats (the decoders are the engines' shader code, cited; the encoders invert them):

Godot 4, ``LightmapGI.directional`` (4 layers per lightmap slice in the texture array: L0, L1
m = -1, 0, 1, that is y, z, x). Godot's shader reads them as

    packed (newer Godot 4: the lightmapper's MODE_PACK_L1_COEFFS pass,
    modules/lightmapper_rd/lm_compute.glsl, stores t = clamp(c / (8 L0) + 0.5, 0, 1); the
    shader, servers/rendering/renderer_rd/shaders/forward_clustered/scene_forward_clustered.glsl,
    evaluates ambient = L0 + sum_m ((t_m - 0.5) * 2) n_m (4 L0)):
        ambient(n) = L0 + n . C1,  with C1 = (t - 0.5) * 8 L0;
    unpacked (earlier Godot 4, the same shader at godotengine/godot@333f0f9):
        ambient(n) = 0.282095 L0 + 0.32573 n . C1.

  ambient(n) multiplies the albedo, so it is E1(n) / pi. Packed: L0 = l0 / (4 pi),
  C1 = l1 / (2 pi), t = 0.5 + l1 / (4 l0) (in [0.25, 0.75]: |l1| <= l0, no clamping). Unpacked:
  L0 = c00, C1 = c1m (0.282095 = Y00 A0 / pi, 0.32573 = Y1 A1 / pi), the SH of the radiance.
  (Godot's own baker approximates these by cosine-weighted rays and writes a direct light so that
  the normal itself gets all of it; hirad writes the projection.)

Bakery SH mode (three extra RGB textures _RNM0, _RNM1, _RNM2 beside the L0 lightmap; its
shader, as reproduced in public Unity shaders that read Bakery's output, e.g. BakerySH in
Bakery's shader includes:  nL1 = tex * 2 - 1,  L1 = nL1 L0 2,
``sh = L0 + n.x L1x + n.y L1y + n.z L1z``). With L0 = l0 / (4 pi) and L1 = l1 / (2 pi) that is
E1(n) / pi again: the lightmap holds L0 = l0 / (4 pi) and _RNM0/1/2 = 0.5 + l1_(x, y, z) / (2 l0)
per channel (in [0, 1]). Bakery's optional non-linear (Geomerics) evaluation reads the same data.

Unity, Directional Mode (``LightmapData.lightmapDir``): "a secondary lightmap, which stores the
incoming dominant light direction and a factor proportional to how much light in the first
lightmap is the result of light coming in along the dominant direction. The rest is then assumed
to come uniformly from the entire hemisphere" (Unity Manual, Lightmap Directional Modes,
https://docs.unity3d.com/2018.4/Documentation/Manual/LightmappingDirectional.html; Unity 6's page,
.../6000.0/Documentation/Manual/LightmappingDirectional.html: "the dominant light direction, along
with a factor describing how much of the total light received comes from that dominant
direction"). The shader (UnityCG.cginc, DecodeDirectionalLightmap):

    halfLambert = dot(n, dir.rgb - 0.5) + 0.5;   out = colour * halfLambert / max(1e-4, dir.a)

"dir is not unit length on purpose. Its length is directionality". With v = dir.rgb - 0.5
(|v| <= 1/2) the shape over normals is 0.5 + n . v; the L1 SH shape is E1(n) proportional to
0.5 + n . l1 / l0. So hirad writes, from the luminance Y of the moments (one direction for the
three channels), v = Y(l1) / Y(l0) shortened to length 1/2 where it is longer (light more
concentrated than L1 can show), dir.rgb = v + 0.5, and the rebalancing dir.a = 0.5 + n . v, so
the texel's own normal decodes to exactly the colour map (E / pi, the plain lightmap), and a
tilted normal n' to E / pi (0.5 + n' . v) / (0.5 + n . v): the ratio E1(n') / E1(n) where v is not
shortened. A uniform hemisphere of radiance L gives v = n / 2, dir.a = 1 and the half-Lambert
pi L (1 + n . n') / 2, its exact irradiance on any tilted normal. dir.a >= 1/2 always (light
from above n has n . l1 >= 0).
"""

from __future__ import annotations

import numpy as np

Y00 = 0.5 / np.sqrt(np.pi)                 # 0.282095
Y1 = np.sqrt(3.0 / (4.0 * np.pi))          # 0.488603
REC709_Y = np.array([0.2126, 0.7152, 0.0722])
SH_L1_AXES = (1, 2, 0)                     # m = -1, 0, 1 are y, z, x


# --- checking and frames --------------------------------------------------------------------

def _moments(l0, l1, normals=None, irradiance=None, to_engine=None):
    l0 = np.asarray(l0, dtype=np.float64)
    l1 = np.asarray(l1, dtype=np.float64)
    if l0.shape[-1:] != (3,):
        raise ValueError(f"l0: expected shape (..., 3) (RGB), got {l0.shape}")
    if l1.shape != l0.shape + (3,):
        raise ValueError(f"l1: expected shape {l0.shape + (3,)} ([..., channel, axis]), got {l1.shape}")
    for name, a in (("l0", l0), ("l1", l1)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: {np.count_nonzero(~np.isfinite(a))} values not finite")
    if np.any(l0 < 0):
        raise ValueError(f"l0: {np.count_nonzero(l0 < 0)} negative values (an integral of radiance is >= 0)")
    out = [l0, l1]
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64)
        if n.shape != l0.shape:
            raise ValueError(f"normals: expected shape {l0.shape}, got {n.shape}")
        if not np.all(np.isfinite(n)) or np.any(np.abs(np.linalg.norm(n, axis=-1) - 1) > 1e-3):
            raise ValueError("normals: not finite or not unit length")
        out.append(n)
    if irradiance is not None:
        e = np.asarray(irradiance, dtype=np.float64)
        if e.shape != l0.shape:
            raise ValueError(f"irradiance: expected shape {l0.shape}, got {e.shape}")
        if not np.all(np.isfinite(e)):
            raise ValueError("irradiance: values not finite")
        out.append(e)
    if to_engine is not None:
        r = np.asarray(to_engine, dtype=np.float64)
        if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-9):
            raise ValueError("to_engine: expected an orthogonal 3x3 matrix (a rotation, or a reflection "
                             "into a left-handed frame)")
        out[1] = out[1] @ r.T
        if normals is not None:
            out[2] = out[2] @ r.T
    return out


def _ratio(num, den):
    """num / den where den > 0, else 0 (an unlit texel has no direction)."""
    den = np.asarray(den, dtype=np.float64)
    safe = np.where(den > 0, den, 1.0)
    return np.where(den > 0, num / safe, 0.0)


# --- L1 spherical harmonics ------------------------------------------------------------------

def sh_l1_coefficients(l0, l1):
    """The radiance's L1 SH coefficients: (c00 (..., 3), c1 (..., 3 channels, 3 for m = -1, 0, 1))."""
    l0, l1 = _moments(l0, l1)
    return Y00 * l0, Y1 * l1[..., list(SH_L1_AXES)]


def sh_l1_irradiance(l0, l1, normals):
    """E1(n) = l0 / 4 + n . l1 / 2 (W/m^2, (..., 3)): the L1 SH's irradiance for unit normals n."""
    l0, l1, n = _moments(l0, l1, normals)
    return l0 / 4 + np.einsum("...ca,...a->...c", l1, n) / 2


# --- Godot 4 ---------------------------------------------------------------------------------

def godot_directional_layers(l0, l1, to_engine=None, packed: bool = True) -> np.ndarray:
    """The 4 layers of one slice of Godot 4's directional lightmap, (4, ..., 3) float32:
    [L0, L1 m=-1 (y), L1 m=0 (z), L1 m=1 (x)]. packed: L0 = l0 / (4 pi) and the L1 layers
    0.5 + l1 / (4 l0) (newer Godot 4's packing); otherwise the raw SH coefficients c00, c1m of
    the radiance (earlier Godot 4)."""
    l0, l1 = _moments(l0, l1, to_engine=to_engine)
    out = np.empty((4,) + l0.shape, dtype=np.float64)
    if packed:
        out[0] = l0 / (4 * np.pi)
        for k, a in enumerate(SH_L1_AXES):
            out[k + 1] = 0.5 + _ratio(l1[..., a], 4 * l0)
    else:
        out[0] = Y00 * l0
        for k, a in enumerate(SH_L1_AXES):
            out[k + 1] = Y1 * l1[..., a]
    return out.astype(np.float32)


def godot_directional_decode(layers, normals, packed: bool = True) -> np.ndarray:
    """Godot's shader on the layers: ambient(n) (..., 3), E1(n) / pi; normals in the engine frame."""
    layers = np.asarray(layers, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if layers.shape[0] != 4 or layers.shape[1:] != n.shape:
        raise ValueError(f"layers: expected shape (4,) + {n.shape}, got {layers.shape}")
    ny, nz, nx = (n[..., a:a + 1] for a in SH_L1_AXES)
    if packed:
        l0 = layers[0]
        c = [(layers[k] - 0.5) * 2.0 for k in (1, 2, 3)]
        return l0 + c[0] * ny * (l0 * 4.0) + c[1] * nz * (l0 * 4.0) + c[2] * nx * (l0 * 4.0)
    return layers[0] * 0.282095 + 0.32573 * (layers[1] * ny + layers[2] * nz + layers[3] * nx)


# --- Bakery SH -------------------------------------------------------------------------------

def bakery_sh_textures(l0, l1, to_engine=None) -> dict:
    """Bakery's SH mode: {"L0": (..., 3) the lightmap, l0 / (4 pi); "RNM0", "RNM1", "RNM2":
    (..., 3) in [0, 1], 0.5 + l1_(x, y, z) / (2 l0) per channel}, float32."""
    l0, l1 = _moments(l0, l1, to_engine=to_engine)
    out = {"L0": (l0 / (4 * np.pi)).astype(np.float32)}
    for a in range(3):
        out[f"RNM{a}"] = (0.5 + _ratio(l1[..., a], 2 * l0)).astype(np.float32)
    return out


def bakery_sh_decode(textures: dict, normals) -> np.ndarray:
    """Bakery's linear SH evaluation: L0 + n . L1 with L1 = (RNM * 2 - 1) L0 2; E1(n) / pi."""
    n = np.asarray(normals, dtype=np.float64)
    l0 = np.asarray(textures["L0"], dtype=np.float64)
    out = l0.copy()
    for a in range(3):
        out += n[..., a:a + 1] * ((np.asarray(textures[f"RNM{a}"], dtype=np.float64) * 2 - 1) * l0 * 2)
    return out


# --- Unity directional -----------------------------------------------------------------------

def unity_dominant_direction(irradiance, l0, l1, normals, to_engine=None):
    """Unity's Directional Mode pair: (colour (..., 3) = E / pi, the plain lightmap; dir (..., 4)
    in [0, 1]: rgb = v + 0.5 with v = Y(l1) / Y(l0) no longer than 1/2, a = 0.5 + n . v), float32.
    Texels without light get v = 0, a = 0.5."""
    l0, l1, n, e = _moments(l0, l1, normals, irradiance, to_engine=to_engine)
    y0 = l0 @ REC709_Y
    y1 = np.einsum("c,...ca->...a", REC709_Y, l1)
    v = _ratio(y1, y0[..., None])
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    v = np.where(length > 0.5, v * _ratio(0.5, length), v)
    d = np.empty(l0.shape[:-1] + (4,), dtype=np.float64)
    d[..., :3] = v + 0.5
    d[..., 3] = 0.5 + np.einsum("...a,...a->...", n, v)
    return (e / np.pi).astype(np.float32), np.clip(d, 0.0, 1.0).astype(np.float32)


def unity_decode_directional(colour, direction, normals) -> np.ndarray:
    """UnityCG.cginc's DecodeDirectionalLightmap: colour (dot(n, dir.rgb - 0.5) + 0.5) / max(1e-4, dir.a)."""
    colour = np.asarray(colour, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    half_lambert = np.einsum("...a,...a->...", n, d[..., :3] - 0.5) + 0.5
    return colour * (half_lambert / np.maximum(1e-4, d[..., 3]))[..., None]
