"""Analytic BRDFs of paper 000 (Table 3) plus Lambert and anisotropic Ward, in NumPy.

Frame and units. Directions are unit vectors in the local shading frame, shape (..., 3):
z is the shading normal N, x the tangent (the anisotropic Ward's αx axis), y = z × x.
``wi`` points from the surface towards the light (L), ``wo`` towards the viewer (V); both
leave the surface. BRDF values are in 1/sr. H = (L + V)/|L + V| is the half vector and
δ = ∠(N, H). Every BRDF is zero unless N·L > 0 and N·V > 0.

A material's BRDF is ``kd/π + ρs ⊙ f_F(ωi, ωo) · f_E(γ, x(ωi, ωo))``: ``kd`` the diffuse
RGB albedo, ``ρs`` the specular RGB colour (the scene's ``specular``), f_F the fixed and
f_E the edited term of Table 4, x the PCA coordinate of the model (δ for most, see each
model). The product f_F · f_E is exactly the Table 3 formula with ρs = 1, except for
Ashikhmin-Shirley whose Table 3 form has no ρs (ρs = 1 gives it).

Fresnel (Cook-Torrance, Ashikhmin-Shirley): Schlick's approximation
F = F0 + (1 − F0)(1 − V·H)⁵, with F0 = ``f0`` or ((ior − 1)/(ior + 1))², default 0.04.
G (Cook-Torrance): min{1, 2(N·H)(N·V)/(V·H), 2(N·H)(N·L)/(V·H)} (Torrance-Sparrow).

Normalizations as in the paper, which are not all energy conserving (measured directional
albedos: decision 0013): Blinn-Phong uses the Phong lobe's (γ + 2)/2π on the half
vector (albedo up to ≈ 4ρs at normal incidence for large γ); Cook-Torrance keeps the
1982 paper's 1/π with a Beckmann D without 1/π (4/π times microfacet theory's 1/4).

The OpenCL twin of this module is ``kernels/brdf.h``; tests hold the two together.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

MODEL_CODES = {
    "lambert": 0,
    "blinn_phong": 1,
    "ward": 2,
    "ward_duer": 3,
    "ward_anisotropic": 4,
    "lafortune": 5,
    "cook_torrance": 6,
    "ashikhmin_shirley": 7,
}
# Material row layout for OpenCL (kernels/brdf.h): model, kd rgb, ρs rgb, γ, alpha_ratio,
# cxy, cz, f0; padded to MATERIAL_FLOATS.
MATERIAL_FLOATS = 16
DEFAULT_F0 = 0.04


@dataclass(frozen=True)
class BrdfParams:
    """The numbers a BRDF evaluation needs, resolved from a scene material."""

    model: str
    albedo: tuple[float, float, float]
    specular: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gamma: float = 1.0
    alpha_ratio: float = 1.0
    cxy: float = -1.0
    cz: float = 1.0
    f0: float = DEFAULT_F0

    @classmethod
    def from_material(cls, model: str, albedo: Any, params: dict[str, Any]) -> BrdfParams:
        """From a scene material's ``model``, ``albedo`` and ``params`` (scene.Material)."""
        if model == "lambert":
            return cls(model, tuple(albedo))
        f0 = params.get("f0", DEFAULT_F0)
        if "ior" in params:
            f0 = ((params["ior"] - 1.0) / (params["ior"] + 1.0)) ** 2
        return cls(model, tuple(albedo), tuple(params["specular"]), params["gamma"],
                   params.get("alpha_ratio", 1.0), params.get("cxy", -1.0),
                   params.get("cz", 1.0), f0)


# ----------------------------------------------------------------------- geometric terms


def half_vector(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Unit half vectors (..., 3); undefined (zero) where wi = −wo."""
    s = wi + wo
    length = np.linalg.norm(s, axis=-1, keepdims=True)
    return s / np.where(length > 0.0, length, 1.0)


def schlick_fresnel(f0: float, v_dot_h: np.ndarray) -> np.ndarray:
    """Schlick's F = F0 + (1 − F0)(1 − V·H)⁵."""
    return f0 + (1.0 - f0) * (1.0 - np.clip(v_dot_h, 0.0, 1.0)) ** 5


def torrance_sparrow_g(n_dot_h, n_dot_l, n_dot_v, v_dot_h) -> np.ndarray:
    """G = min{1, 2(N·H)(N·V)/(V·H), 2(N·H)(N·L)/(V·H)}."""
    vh = np.maximum(v_dot_h, 1e-30)
    return np.minimum(1.0, np.minimum(2.0 * n_dot_h * n_dot_v / vh, 2.0 * n_dot_h * n_dot_l / vh))


def tan2(cos_delta: np.ndarray) -> np.ndarray:
    """tan²δ from cos δ ∈ (0, 1]."""
    c2 = np.maximum(cos_delta * cos_delta, 1e-300)
    return np.maximum(1.0 - c2, 0.0) / c2


# ---------------------------------------------------------------------------- the models
# Each model gives its PCA coordinate x(ωi, ωo), its fixed term f_F(ωi, ωo) (without ρs)
# and its edited term f_E(γ, x). γ and x broadcast against each other.


def _cos_power_lobe(gamma, cos_delta, scale):
    """scale(γ) · cos^γ δ, with cos δ clamped to [0, 1]."""
    return scale * np.clip(cos_delta, 0.0, 1.0) ** gamma


def _gaussian_lobe(gamma, cos_delta, scale):
    """exp(−tan²δ / γ²) · scale(γ)."""
    return np.exp(-tan2(np.clip(cos_delta, 0.0, 1.0)) / (gamma * gamma)) * scale


class BlinnPhong:
    """f = ρs (γ + 2)/(2π) cos^γ δ. f_F = 1, f_E = (γ + 2)/(2π) cos^γ δ, x = δ."""

    @staticmethod
    def edited(gamma, x, p: BrdfParams):
        return _cos_power_lobe(gamma, np.cos(x), (gamma + 2.0) / (2.0 * np.pi))

    @staticmethod
    def fixed(wi, wo, h, p: BrdfParams):
        return np.ones(np.broadcast_shapes(wi.shape, wo.shape)[:-1])


class Ward:
    """Isotropic Ward: f = ρs / √(N·L N·V) · exp(−tan²δ/γ²)/(4πγ²), γ the roughness α.
    f_F = 1/√(N·L N·V), f_E = exp(−tan²δ/γ²)/(4πγ²), x = δ."""

    @staticmethod
    def edited(gamma, x, p: BrdfParams):
        return _gaussian_lobe(gamma, np.cos(x), 1.0 / (4.0 * np.pi * gamma * gamma))

    @staticmethod
    def fixed(wi, wo, h, p: BrdfParams):
        return 1.0 / np.sqrt(wi[..., 2] * wo[..., 2])


class WardDuer(Ward):
    """Ward-Dür: f = ρs / (N·L N·V) · exp(−tan²δ/γ²)/(4πγ²). f_F = 1/(N·L N·V), f_E as
    Ward's, x = δ."""

    @staticmethod
    def fixed(wi, wo, h, p: BrdfParams):
        return 1.0 / (wi[..., 2] * wo[..., 2])


class WardAnisotropic:
    """Anisotropic Ward (paper 004 Fig. 11) with αx = γ, αy = r·γ (r = ``alpha_ratio``):
    f = ρs / √(N·L N·V) · exp(−tan²δ (cos²φ/αx² + sin²φ/αy²)) / (4π αx αy), φ the
    azimuth of H from the tangent. f_F = 1/√(N·L N·V). The exponent is tan²δ_e / γ² with
    the effective angle δ_e = arctan(tan δ · √(cos²φ + sin²φ/r²)) ∈ [0, π/2], so the edited
    term is the 1D family f_E = exp(−tan²δ_e/γ²)/(4π r γ²) and x = δ_e."""

    @staticmethod
    def edited(gamma, x, p: BrdfParams):
        return _gaussian_lobe(gamma, np.cos(x),
                              1.0 / (4.0 * np.pi * p.alpha_ratio * gamma * gamma))

    fixed = Ward.fixed


class Lafortune:
    """Isotropic one-lobe Lafortune: f = ρs (γ + 2)/(2π) · x^γ with
    x = max(0, Cxy lx vx + Cxy ly vy + Cz lz vz) / max(|Cxy|, |Cz|) ∈ [0, 1] (Cxy = −1,
    Cz = 1 is the Phong lobe (R·V)^γ). Table 3 prints max(Cx, Cy, Cz) without bars; with
    negative Cxy only max|C| keeps x ≤ 1, as §4 writes. f_F = 1, f_E = (γ + 2)/(2π) x^γ."""

    @staticmethod
    def edited(gamma, x, p: BrdfParams):
        return _cos_power_lobe(gamma, x, (gamma + 2.0) / (2.0 * np.pi))

    @staticmethod
    def fixed(wi, wo, h, p: BrdfParams):
        return np.ones(np.broadcast_shapes(wi.shape, wo.shape)[:-1])


class CookTorrance:
    """Cook-Torrance (1982): f = ρs/π · D G F / (N·L N·V) with Beckmann
    D = exp(−tan²δ/γ²) / (γ² cos⁴δ), γ the rms slope m. f_F = G F / (N·L N·V cos⁴δ),
    f_E = exp(−tan²δ/γ²)/(πγ²), x = δ."""

    @staticmethod
    def edited(gamma, x, p: BrdfParams):
        return _gaussian_lobe(gamma, np.cos(x), 1.0 / (np.pi * gamma * gamma))

    @staticmethod
    def fixed(wi, wo, h, p: BrdfParams):
        nl, nv, nh = wi[..., 2], wo[..., 2], h[..., 2]
        vh = np.sum(wo * h, axis=-1)
        g = torrance_sparrow_g(nh, nl, nv, vh)
        return g * schlick_fresnel(p.f0, vh) / (nl * nv * np.maximum(nh, 1e-30) ** 4)


class AshikhminShirley:
    """Isotropic Ashikhmin-Shirley specular term: f = ρs (γ + 1)/(8π) (N·H)^γ /
    ((V·H) max(N·L, N·V)) · F. f_F = F / ((V·H) max(N·L, N·V)),
    f_E = (γ + 1)/(8π) cos^γ δ, x = δ."""

    @staticmethod
    def edited(gamma, x, p: BrdfParams):
        return _cos_power_lobe(gamma, np.cos(x), (gamma + 1.0) / (8.0 * np.pi))

    @staticmethod
    def fixed(wi, wo, h, p: BrdfParams):
        vh = np.sum(wo * h, axis=-1)
        return schlick_fresnel(p.f0, vh) / (np.maximum(vh, 1e-30)
                                            * np.maximum(wi[..., 2], wo[..., 2]))


MODELS = {
    "blinn_phong": BlinnPhong,
    "ward": Ward,
    "ward_duer": WardDuer,
    "ward_anisotropic": WardAnisotropic,
    "lafortune": Lafortune,
    "cook_torrance": CookTorrance,
    "ashikhmin_shirley": AshikhminShirley,
}


# --------------------------------------------------------------------- scene parameters


@dataclass(frozen=True)
class SceneParam:
    """One key that a material of a model takes in a scene file (besides ``model``).

    ``kind`` is ``number`` (a finite number), ``rgb`` (a number or a list of three, each
    in the allowed range; a number means grey) or ``range`` (``[min, max]``, each in the
    allowed range, with ``lo < min < max``). The allowed range is ``[lo, hi]``, or
    ``(lo, hi]`` when ``lo_open``; ``within`` names a ``range`` parameter of the same
    material that, when given, is the allowed range instead. ``default`` is the value the
    model uses when the key is absent (None: there is none); with ``filled`` the loaded
    material holds it, without the key stays absent from the material. ``required`` keys
    must be given."""

    name: str
    kind: Literal["number", "rgb", "range"]
    doc: str
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    default: float | None = None
    filled: bool = False
    required: bool = False
    within: str | None = None


@dataclass(frozen=True)
class ModelParams:
    """The scene parameters of one material model, in validation order, and the ``rule``
    that ties them, if any: given the material's keys and values, the problem with their
    combination or None."""

    params: tuple[SceneParam, ...]
    rule: Callable[[dict[str, Any]], str | None] | None = None

    @property
    def names(self) -> tuple[str, ...]:
        """The keys, in validation order."""
        return tuple(p.name for p in self.params)


def _one_fresnel(given: dict[str, Any]) -> str | None:
    """Fresnel models take F0 directly or from the IOR, not both."""
    if "f0" in given and "ior" in given:
        return "give either f0 or ior (F0 = ((ior-1)/(ior+1))^2), not both"
    return None


def _lafortune_lobe(given: dict[str, Any]) -> str | None:
    """Lafortune's coordinate divides by max(|Cxy|, |Cz|)."""
    if max(abs(given.get("cxy", -1.0)), abs(given.get("cz", 1.0))) == 0.0:
        return "cxy and cz cannot both be zero"
    return None


ALBEDO = SceneParam("albedo", "rgb", "diffuse albedo kd (linear RGB)", lo=0.0, hi=1.0,
                    default=0.8, filled=True)
# The glossy models' common keys. gamma_range and pca_tolerance are method d2i's settings
# (the range its PCA basis covers, its own truncation tolerance); d2i checks their presence.
# The default ρs keeps a material of default albedo within energy conservation for every
# model whose specular albedo is bounded (≤ 4, see specular_albedo_bound): 0.8 + 0.04 × 4.
_SPECULAR = SceneParam("specular", "rgb", "specular colour ρs (linear RGB)", lo=0.0, hi=1.0,
                       default=0.04, filled=True)
_GAMMA_RANGE = SceneParam("gamma_range", "range", "[γmin, γmax] the PCA basis covers "
                          "(method d2i); γ must lie in it", lo=0.0)
_PCA_TOLERANCE = SceneParam("pca_tolerance", "number", "worst relative RMS of the PCA basis "
                            "(method d2i; default: param brdf_basis.tolerance)",
                            lo=1e-9, hi=0.5)
_FRESNEL = (
    SceneParam("f0", "number", "Schlick's Fresnel reflectance at normal incidence",
               lo=0.0, hi=1.0, default=DEFAULT_F0),
    SceneParam("ior", "number", "index of refraction, F0 = ((ior − 1)/(ior + 1))² "
               "(instead of f0)", lo=1.0, hi=10.0),
)


def _glossy(gamma_doc: str, *own: SceneParam, least: float = 0.0
            ) -> tuple[SceneParam, ...]:
    """Albedo, γ (described by ``gamma_doc``, above ``least``) with its range, ρs, the
    model's ``own`` keys and pca_tolerance."""
    gamma = SceneParam("gamma", "number", gamma_doc, lo=least, lo_open=True, required=True,
                       within="gamma_range")
    gamma_range = _GAMMA_RANGE if least == 0.0 else SceneParam(
        _GAMMA_RANGE.name, "range", _GAMMA_RANGE.doc, lo=least)
    return (ALBEDO, gamma_range, gamma, _SPECULAR, *own, _PCA_TOLERANCE)


# A roughness (Ward's α, Beckmann's m) above this: a narrower lobe falls between the
# samples of the BRDF tables and bases (brdf_basis's δ grid is π/2 / 1024 ≈ 1.5e-3 rad
# apart, offset by half a step), which then hold only zeros: α = 1e-12 made brdf_basis
# divide by a zero norm.
LEAST_ROUGHNESS = 5e-4


# Each material model's scene parameters; the order of the models is the order in which
# messages list them.
MATERIAL_PARAMETERS: dict[str, ModelParams] = {
    "lambert": ModelParams((ALBEDO,)),
    "blinn_phong": ModelParams(_glossy("Phong exponent γ (editable)")),
    "ward": ModelParams(_glossy("roughness α = γ (editable)", least=LEAST_ROUGHNESS)),
    "ward_duer": ModelParams(_glossy("roughness α = γ (editable)", least=LEAST_ROUGHNESS)),
    "ward_anisotropic": ModelParams(_glossy(
        "roughness αx = γ (editable)",
        SceneParam("alpha_ratio", "number", "anisotropy αy/αx", lo=1e-3, hi=1e3,
                   default=1.0), least=LEAST_ROUGHNESS)),
    "lafortune": ModelParams(_glossy(
        "lobe exponent γ (editable)",
        SceneParam("cxy", "number", "lobe coefficient Cxy", lo=-1e3, hi=1e3, default=-1.0),
        SceneParam("cz", "number", "lobe coefficient Cz", lo=-1e3, hi=1e3, default=1.0)),
        rule=_lafortune_lobe),
    "cook_torrance": ModelParams(_glossy("Beckmann rms slope m = γ (editable)", *_FRESNEL,
                                         least=LEAST_ROUGHNESS), rule=_one_fresnel),
    "ashikhmin_shirley": ModelParams(_glossy("lobe exponent γ (editable)", *_FRESNEL),
                                     rule=_one_fresnel),
}


# ------------------------------------------------------------------------ energy bound


def specular_albedo_bound(model: str, gamma_max: float) -> float | None:
    """An upper bound of the glossy term's directional albedo ∫ f_F f_E cosθi dωi (ρs = 1)
    over every outgoing direction and every γ ≤ ``gamma_max`` (the largest γ the material
    can be edited to), with Fresnel F ≤ 1: a material with kd + ρs · bound ≤ 1 per channel
    never reflects more than it receives. None where no finite bound exists.

    Measured with :func:`directional_albedo` (1024 × 256, θo = 0..89°, ρs = F0 = 1;
    decision 0013): Blinn-Phong peaks at normal incidence, where its albedo is the closed form
    below (1.37 at γ = 1, 3.95 at γ = 300, → 4); Cook-Torrance's 1982 normalisation
    reaches 4 for smooth surfaces (and near grazing for any roughness); Ward ≤ 0.993,
    anisotropic Ward ≤ 0.965, Lafortune 1.000 (normal incidence, Phong lobe),
    Ashikhmin-Shirley ≤ 0.987 — bound 1. Ward-Dür's 1/(N·L N·V) has none: its albedo
    grows towards grazing (5.06 at θo = 89°, γ = 0.46) for every γ."""
    if model == "lambert":
        return 0.0
    if model == "blinn_phong":
        # (γ+2) ∫ cos^γ(θ/2) cosθ sinθ dθ over [0, π/2], with c = cos(θ/2), s = 1/√2
        g, s = gamma_max, math.sqrt(0.5)
        return 4.0 * (g + 2.0) * (2.0 * (1.0 - s ** (g + 4.0)) / (g + 4.0)
                                  - (1.0 - s ** (g + 2.0)) / (g + 2.0))
    if model == "cook_torrance":
        return 4.0
    if model == "ward_duer":
        return None
    return 1.0


# --------------------------------------------------------------------------- evaluation


def coordinate(wi: np.ndarray, wo: np.ndarray, p: BrdfParams) -> np.ndarray:
    """The model's PCA coordinate x(ωi, ωo), shape (...,): δ = arccos(N·H) ∈ [0, π/2];
    Lafortune's normalised lobe base ∈ [0, 1]; the anisotropic Ward's effective δ_e."""
    if p.model == "lafortune":
        c = np.array([p.cxy, p.cxy, p.cz])
        lobe = np.sum(c * wi * wo, axis=-1) / max(abs(p.cxy), abs(p.cz))
        return np.clip(lobe, 0.0, 1.0)
    s = wi + wo
    sxy2 = s[..., 0] ** 2 + s[..., 1] ** 2
    if p.model == "ward_anisotropic":
        sxy2 = s[..., 0] ** 2 + s[..., 1] ** 2 / p.alpha_ratio ** 2
    return np.arctan2(np.sqrt(sxy2), np.maximum(s[..., 2], 0.0))


def fixed_term(wi: np.ndarray, wo: np.ndarray, p: BrdfParams) -> np.ndarray:
    """f_F(ωi, ωo) without ρs (...,), zero below either horizon."""
    above = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
    wi = np.where(above[..., None], wi, [0.0, 0.0, 1.0])
    wo = np.where(above[..., None], wo, [0.0, 0.0, 1.0])
    return np.where(above, MODELS[p.model].fixed(wi, wo, half_vector(wi, wo), p), 0.0)


def edited_term(gamma: Any, x: np.ndarray, p: BrdfParams) -> np.ndarray:
    """f_E(γ, x); ``x`` as from :func:`coordinate`; γ broadcasts against x."""
    return MODELS[p.model].edited(np.asarray(gamma, np.float64), np.asarray(x, np.float64), p)


def glossy(wi: np.ndarray, wo: np.ndarray, p: BrdfParams, gamma: float | None = None
           ) -> np.ndarray:
    """f_F · f_E without ρs (...,), at the material's γ unless ``gamma`` is given."""
    if p.model == "lambert":
        return np.zeros(np.broadcast_shapes(wi.shape, wo.shape)[:-1])
    g = p.gamma if gamma is None else gamma
    f_e = edited_term(g, coordinate(wi, wo, p), p)
    with np.errstate(invalid="ignore"):
        out = fixed_term(wi, wo, p) * f_e
    return np.where(f_e > 0.0, out, 0.0)


def evaluate(wi: np.ndarray, wo: np.ndarray, p: BrdfParams) -> np.ndarray:
    """The full BRDF kd/π + ρs f_F f_E, RGB (..., 3) in 1/sr."""
    wi = np.asarray(wi, np.float64)
    wo = np.asarray(wo, np.float64)
    above = ((wi[..., 2] > 0.0) & (wo[..., 2] > 0.0))[..., None]
    diffuse = np.asarray(p.albedo) / np.pi
    return np.where(above, diffuse + np.asarray(p.specular) * glossy(wi, wo, p)[..., None], 0.0)


def to_local(v: np.ndarray, normal: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """World vectors (..., 3) in the frame (tangent, normal × tangent, normal)."""
    bitangent = np.cross(normal, tangent)
    return np.stack([np.sum(v * tangent, -1), np.sum(v * bitangent, -1),
                     np.sum(v * normal, -1)], axis=-1)


def scene_brdfs(scene: Any, names: list[str]) -> list[BrdfParams]:
    """BRDF parameters of the scene's materials ``names``, in that order."""
    return [BrdfParams.from_material(scene.materials[n].model, scene.materials[n].albedo,
                                     scene.materials[n].params) for n in names]


def pack_materials(materials: list[BrdfParams]) -> np.ndarray:
    """Rows of MATERIAL_FLOATS float32 for kernels/brdf.h (layout in its header)."""
    rows = np.zeros((max(len(materials), 1), MATERIAL_FLOATS), np.float32)
    for row, p in zip(rows, materials, strict=False):
        row[0] = MODEL_CODES[p.model]
        row[1:4] = p.albedo
        row[4:7] = p.specular
        row[7] = p.gamma
        row[8] = p.alpha_ratio
        row[9] = p.cxy
        row[10] = p.cz
        row[11] = p.f0
    return rows


def evaluate_world(wi: np.ndarray, wo: np.ndarray, normal: np.ndarray, tangent: np.ndarray,
                   material: np.ndarray, materials: list[BrdfParams]) -> np.ndarray:
    """BRDF values (N, S, 3) at N points for S world directions ``wi`` (N, S, 3) each,
    towards world ``wo`` (N, 3), in the frames ``normal``, ``tangent`` (N, 3), with
    per-point indices ``material`` (N,) into ``materials``."""
    li = to_local(wi, normal[:, None, :], tangent[:, None, :])
    lo = np.broadcast_to(to_local(wo, normal, tangent)[:, None, :], li.shape)
    out = np.zeros(li.shape)
    for index in np.unique(material):
        sel = material == index
        out[sel] = evaluate(li[sel], lo[sel], materials[index])
    return out


def directional_albedo(f: Any, wo: np.ndarray, n_theta: int = 2048, n_phi: int = 512
                       ) -> float:
    """∫ f(ωi) cosθi dωi over the upper hemisphere for one outgoing ``wo`` (3,), by the
    midpoint rule in half-vector coordinates (θh ∈ [0, π/2], φh ∈ [0, 2π]), where glossy
    lobes are compact: ωi = 2(ωo·h)h − ωo and dωi = 4(ωo·h) sinθh dθh dφh. ``f`` maps
    (..., 3) directions to (...,) values."""
    th = (np.arange(n_theta) + 0.5) * (0.5 * np.pi / n_theta)
    ph = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    st, ct = np.sin(th)[:, None], np.cos(th)[:, None]
    h = np.stack(np.broadcast_arrays(st * np.cos(ph), st * np.sin(ph), ct), axis=-1)
    oh = h @ wo
    wi = 2.0 * oh[..., None] * h - wo
    ok = (oh > 0.0) & (wi[..., 2] > 0.0)
    wi = np.where(ok[..., None], wi, [0.0, 0.0, 1.0])
    integrand = np.where(ok, f(wi) * wi[..., 2] * 4.0 * oh * st, 0.0)
    return float(integrand.sum() * (0.5 * np.pi / n_theta) * (2.0 * np.pi / n_phi))
