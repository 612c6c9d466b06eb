"""The project's analytic BRDFs as Mitsuba 3 Python BSDFs, for the Mitsuba cross-check.

Written from the formulas (paper 000 Table 3, paper 004 for anisotropic Ward, the
Ashikhmin-Shirley and Cook-Torrance papers) as the project states them, independently of
``pipeline.math.brdf`` (not imported here): two implementations that agree are the point
of the cross-check (tests/test_mitsuba.py compares them at random directions).

Frame and units. ``L`` points from the surface towards the light, ``V`` towards the viewer
(Mitsuba's ``si.wi`` is V, the BSDF's ``wo`` argument is L); both leave the surface. All
values are in 1/sr. Local shading frame: z the shading normal N, x the tangent T, y = N × T;
H = (L + V)/|L + V|, δ = ∠(N, H). Every model is kd/π + ρs · f_glossy with ``kd`` the
diffuse albedo and ``ρs`` the specular colour (RGB), and is zero unless N·L > 0 and N·V > 0:

``blinn_phong``        f = ρs (γ + 2)/(2π) (N·H)^γ
``ward``               f = ρs / √(N·L N·V) · exp(−tan²δ/α²) / (4π α²),        α = γ
``ward_duer``          f = ρs / (N·L N·V)  · exp(−tan²δ/α²) / (4π α²),        α = γ
``ward_anisotropic``   f = ρs / √(N·L N·V) · exp(−(Hx²/αx² + Hy²/αy²)/Hz²) / (4π αx αy),
                       αx = γ along T, αy = r γ (r = ``alpha_ratio``)
``lafortune``          f = ρs (γ + 2)/(2π) · (max(0, Cxy (Lx Vx + Ly Vy) + Cz Lz Vz)
                       / max(|Cxy|, |Cz|))^γ   (the base is ≤ 1 by Cauchy-Schwarz)
``cook_torrance``      f = ρs/π · D G F / (N·L N·V), Beckmann D = exp(−tan²δ/m²)/(m² cos⁴δ)
                       (the 1982 paper's, without 1/π), m = γ,
                       G = min{1, 2 (N·H)(N·V)/(V·H), 2 (N·H)(N·L)/(V·H)}
``ashikhmin_shirley``  f = ρs (γ + 1)/(8π) (N·H)^γ / ((V·H) max(N·L, N·V)) · F

F is Schlick's F0 + (1 − F0)(1 − V·H)⁵ with F0 = ``f0``.

Frame conventions of the project's renderers (pipeline/device/raytrace.py ``Surface``),
matched here: the shading normal is the blend of vertex normals (Mitsuba's
``si.sh_frame.n``), turned to face the viewer when the *face* normal faces away from it
(two-sided shading); the tangent is the face's dP/du (from the mesh uv, passed as the mesh
face attribute ``face_dpdu``, zero where the uv mapping is degenerate) made orthogonal to
that normal, or, where that fails, the Duff et al. (2017) tangent of the turned normal
(``mi.coordinate_system``, the same construction). A light direction behind the triangle's
plane (on the other side of the face normal from the viewer) carries nothing.

Sampling: with probability ½ a cosine-weighted hemisphere direction, else the mirror of V
about a half vector drawn from a Beckmann distribution roughly matched to the lobe
(``mi.MicrofacetDistribution``); ``pdf`` is that mixture's density, so eval, pdf and
sample are consistent whatever the match.
"""

from __future__ import annotations

import math
from typing import Any

MODELS = ("lambert", "blinn_phong", "ward", "ward_duer", "ward_anisotropic", "lafortune",
          "cook_torrance", "ashikhmin_shirley")
PLUGIN = "prt_brdf"
TANGENT_ATTRIBUTE = "face_dpdu"
DEFAULT_F0 = 0.04  # Schlick's F0 where a material gives neither f0 nor ior
_registered: set[str] = set()


def register(mi: Any) -> None:
    """Registers the plugin ``prt_brdf`` for the active variant (once per variant).
    Its properties: ``model`` (one of :data:`MODELS`), ``kd_r/g/b``, ``ks_r/g/b`` (ρs),
    ``gamma``, ``alpha_ratio``, ``cxy``, ``cz``, ``f0``."""
    if mi.variant() in _registered:
        return
    cls = _bsdf_class(mi)
    mi.register_bsdf(PLUGIN, lambda props: cls(props))
    _registered.add(mi.variant())


def _bsdf_class(mi: Any) -> type:
    import drjit as dr

    inv_pi = 1.0 / math.pi

    class ProjectBrdf(mi.BSDF):
        def __init__(self, props: Any) -> None:
            mi.BSDF.__init__(self, props)
            self.model = str(props.get("model", "lambert"))
            if self.model not in MODELS:
                raise ValueError(f"prt_brdf: unknown model {self.model!r}")
            self.kd = mi.Color3f(*(float(props.get(f"kd_{c}", 0.5)) for c in "rgb"))
            self.ks = mi.Color3f(*(float(props.get(f"ks_{c}", 0.0)) for c in "rgb"))
            self.gamma = float(props.get("gamma", 1.0))
            self.alpha_ratio = float(props.get("alpha_ratio", 1.0))
            self.cxy = float(props.get("cxy", -1.0))
            self.cz = float(props.get("cz", 1.0))
            self.f0 = float(props.get("f0", DEFAULT_F0))
            self.glossy = self.model != "lambert"
            # The lobe sampler's Beckmann roughness: Ward/Cook-Torrance their own α;
            # cos^γ δ ≈ exp(−γδ²/2) → α² = 2/γ; Lafortune's (R·V)^γ ≈ exp(−2γδ²) → 1/(2γ).
            g = self.gamma
            if self.model in ("ward", "ward_duer", "cook_torrance"):
                ax = ay = g
            elif self.model == "ward_anisotropic":
                ax, ay = g, g * self.alpha_ratio
            elif self.model == "lafortune":
                ax = ay = math.sqrt(1.0 / (2.0 * g + 2.0))
            else:
                ax = ay = math.sqrt(2.0 / (g + 2.0))
            ax, ay = min(max(ax, 1e-3), 1.5), min(max(ay, 1e-3), 1.5)
            self.lobe = mi.MicrofacetDistribution(mi.MicrofacetType.Beckmann, ax, ay, False)
            self.lobe_prob = 0.5 if self.glossy else 0.0
            reflection = (mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
                          | mi.BSDFFlags.BackSide)
            if self.glossy:
                reflection = reflection | mi.BSDFFlags.GlossyReflection
            self.m_components = [reflection]
            self.m_flags = reflection

        # ------------------------------------------------------------- frame
        def _frame(self, si: Any, active: Any) -> tuple[Any, Any, Any, Any, Any]:
            """(T, B, N, V local, whether V faces the face normal) at ``si``."""
            v_world = si.to_world(si.wi)
            front = dr.dot(si.n, v_world) >= 0.0
            n = dr.select(front, si.sh_frame.n, -si.sh_frame.n)
            dpdu = mi.Vector3f(si.shape.eval_attribute_3(TANGENT_ATTRIBUTE, si, active))
            t = dpdu - n * dr.dot(n, dpdu)
            length = dr.norm(t)
            fallback = mi.coordinate_system(n)[0]
            t = dr.select(length > 1e-8, t / dr.maximum(length, 1e-30), fallback)
            b = dr.cross(n, t)
            v = mi.Vector3f(dr.dot(v_world, t), dr.dot(v_world, b), dr.dot(v_world, n))
            return t, b, n, v, front

        def _local_light(self, si: Any, wo: Any, frame: Any) -> tuple[Any, Any]:
            """L (Mitsuba's ``wo``, shading-frame local) in our local frame, and whether
            it lies on the viewer's side of the triangle's plane."""
            t, b, n, _, front = frame
            l_world = si.to_world(wo)
            same_side = dr.select(front, dr.dot(si.n, l_world) > 0.0,
                                  dr.dot(si.n, l_world) < 0.0)
            return mi.Vector3f(dr.dot(l_world, t), dr.dot(l_world, b),
                               dr.dot(l_world, n)), same_side

        # ------------------------------------------------------------- the models
        def _glossy(self, lv: Any, vv: Any) -> Any:
            """f_glossy (without ρs), 1/sr; L and V local with positive z."""
            g, m = self.gamma, self.model
            nl, nv = lv.z, vv.z
            h = dr.normalize(lv + vv)
            nh = dr.maximum(h.z, 0.0)
            vh = dr.maximum(dr.dot(vv, h), 1e-30)
            nh2 = dr.maximum(nh * nh, 1e-30)
            tan2 = dr.maximum(1.0 - nh2, 0.0) / nh2
            if m == "blinn_phong":
                return (g + 2.0) / (2.0 * math.pi) * dr.power(nh, g)
            if m in ("ward", "ward_duer"):
                lobe = dr.exp(-tan2 / (g * g)) / (4.0 * math.pi * g * g)
                geo = nl * nv if m == "ward_duer" else dr.sqrt(nl * nv)
                return lobe / geo
            if m == "ward_anisotropic":
                ax, ay = g, g * self.alpha_ratio
                expo = (h.x * h.x / (ax * ax) + h.y * h.y / (ay * ay)) / nh2
                return dr.exp(-expo) / (4.0 * math.pi * ax * ay) / dr.sqrt(nl * nv)
            if m == "lafortune":
                base = (self.cxy * (lv.x * vv.x + lv.y * vv.y) + self.cz * lv.z * vv.z) / max(
                    abs(self.cxy), abs(self.cz))
                return (g + 2.0) / (2.0 * math.pi) * dr.power(dr.maximum(base, 0.0), g)
            fresnel = self.f0 + (1.0 - self.f0) * dr.power(1.0 - dr.minimum(vh, 1.0), 5.0)
            if m == "cook_torrance":
                d = dr.exp(-tan2 / (g * g)) / (g * g * nh2 * nh2)
                shadow = dr.minimum(1.0, dr.minimum(2.0 * nh * nv / vh, 2.0 * nh * nl / vh))
                return inv_pi * d * shadow * fresnel / (nl * nv)
            # ashikhmin_shirley
            return ((g + 1.0) / (8.0 * math.pi) * dr.power(nh, g) * fresnel
                    / (vh * dr.maximum(nl, nv)))

        def _value(self, lv: Any, vv: Any, ok: Any) -> Any:
            """f · N·L (Mitsuba's eval includes the foreshortening), RGB."""
            f = self.kd * inv_pi
            if self.glossy:
                f = f + self.ks * self._glossy(lv, vv)
            return dr.select(ok, f * lv.z, 0.0)

        def _density(self, lv: Any, vv: Any, ok: Any) -> Any:
            """The sampling mixture's density of L (solid angle)."""
            pdf = (1.0 - self.lobe_prob) * dr.maximum(lv.z, 0.0) * inv_pi
            if self.glossy:
                h = dr.normalize(lv + vv)
                lh = dr.dot(lv, h)
                ph = dr.select(lh > 0.0, self.lobe.pdf(vv, h) / (4.0 * lh), 0.0)
                pdf = pdf + self.lobe_prob * ph
            return dr.select(ok, pdf, 0.0)

        def _evaluate(self, si: Any, wo: Any, active: Any) -> tuple[Any, Any]:
            frame = self._frame(si, active)
            vv = frame[3]
            lv, same_side = self._local_light(si, wo, frame)
            ok = active & same_side & (lv.z > 0.0) & (vv.z > 0.0)
            return self._value(lv, vv, ok), self._density(lv, vv, ok)

        # ------------------------------------------------------------- interface
        def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            return self._evaluate(si, wo, active)[0]

        def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            return self._evaluate(si, wo, active)[1]

        def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            return self._evaluate(si, wo, active)

        def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any,
                   active: Any = True) -> Any:
            t, b, n, vv, front = frame = self._frame(si, active)
            lv = mi.warp.square_to_cosine_hemisphere(sample2)
            if self.glossy:
                use_lobe = sample1 < self.lobe_prob
                h = self.lobe.sample(vv, sample2)[0]
                lobe_dir = 2.0 * dr.dot(vv, h) * h - vv
                lv = dr.select(use_lobe, lobe_dir, lv)
            l_world = lv.x * t + lv.y * b + lv.z * n
            wo = si.to_local(l_world)
            _, same_side = self._local_light(si, wo, frame)
            ok = active & same_side & (lv.z > 0.0) & (vv.z > 0.0)
            value, pdf = self._value(lv, vv, ok), self._density(lv, vv, ok)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = wo
            bs.pdf = pdf
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection if self.glossy
                                        else +mi.BSDFFlags.DiffuseReflection)
            bs.sampled_component = mi.UInt32(0)
            weight = dr.select(ok & (pdf > 0.0), value / dr.maximum(pdf, 1e-30), 0.0)
            return bs, weight

        def traverse(self, callback: Any) -> None:
            pass

        def parameters_changed(self, keys: Any) -> None:
            pass

        def to_string(self) -> str:
            return f"ProjectBrdf[model={self.model}]"

    return ProjectBrdf
