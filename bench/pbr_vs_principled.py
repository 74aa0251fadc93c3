"""Derives how tessera's dielectric `pbr` (glTF's metallic-roughness material at metallic 0)
differs from Mitsuba 3's `principled` (Burley's Disney BRDF as Mitsuba implements it), by
numerical quadrature of the two models' formulas, written out here from their definitions
(docs/renderer.md, "glTF's material"; Mitsuba 3's src/bsdfs/principled.cpp):

- tessera (its default, `distribution = "multiscatter_ggx"`): f = k(μo) F(o·h, η) D G₂ /
  (4 μo μi) + c (1 − E_c(μo)) / π, with G₂ the height-correlated masking-shadowing,
  k = 1 + F_ms (1 − E₁(μo)) / E₁(μo) Cycles' multiple-scattering compensation (E₁ the lobe's
  albedo for a white Fresnel, Ē₁ its cosine-weighted mean, F_ms = F̄ Ē₁ / (1 − F̄ (1 − Ē₁)),
  F̄ the dielectric Fresnel's cosine-weighted mean), and E_c(μ) = k(μ) E_ss(μ) the coat's
  albedo (E_ss the specular lobe's): the base is albedo-scaled by what the coat leaves at the
  view;
- Mitsuba's principled at metallic 0, specular 0.5 (η = 1.5), no sheen, clearcoat,
  transmission or tint: f = F(o·h, η) D G₁(o) G₁(i) / (4 μo μi)
  + c/π [(1 − Fo/2)(1 − Fi/2) + Rr (Fo + Fi + Fo Fi (Rr − 1))], with F_x = (1 − μx)⁵ and
  Rr = 2 r (i·h)² (r the roughness): Burley's diffuse with its retro-reflection, added to the
  specular lobe with no Fresnel weight between them.

Both use GGX with α = r². It prints each model's directional albedo ρ(θo) (the radiance a
surface returns under a uniform white sky), their ratio by channel, and the ratio of the
radiance averaged over a sphere's visible disc (μo distributed as 2μo), for the base colour of
the first look by hand (0.8, 0.3, 0.2) and for white, at roughness 0.5.

    python3 bench/pbr_vs_principled.py       (NumPy; about ten seconds)
"""
import numpy as np

ETA = 1.5
N = 400  # midpoints per side of the (μi, φ) grid


def fresnel(c, eta):
    """Unpolarised dielectric reflectance at cosine c from the side of relative index eta."""
    c = np.clip(c, 0.0, 1.0)
    s2 = (1 - c * c) / (eta * eta)
    ct = np.sqrt(np.clip(1 - s2, 0.0, None))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return np.where(s2 >= 1, 1.0, 0.5 * (rs * rs + rp * rp))


def lam(alpha, mu):
    tan2 = (1 - mu * mu) / np.maximum(mu * mu, 1e-12)
    return (np.sqrt(1 + alpha * alpha * tan2) - 1) / 2


def ggx(alpha, cos_h):
    a2 = alpha * alpha
    d = cos_h * cos_h * (a2 - 1) + 1
    return a2 / (np.pi * d * d)


def grid():
    mu = (np.arange(N) + 0.5) / N
    phi = (np.arange(N) + 0.5) / N * 2 * np.pi
    mu, phi = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - mu * mu)
    return np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1), (1.0 / N) * (2 * np.pi / N)


WI, DW = grid()


def lobe(mu_o, alpha, eta, correlated):
    """The specular lobe f·μi over the grid for the view at μo (in the xz plane); a white
    Fresnel where `eta` is None."""
    o = np.array([np.sqrt(1 - mu_o * mu_o), 0.0, mu_o])
    h = WI + o
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    mu_i = WI[..., 2]
    o_h = h @ o
    if correlated:
        g = 1 / (1 + lam(alpha, mu_o) + lam(alpha, mu_i))
    else:
        g = 1 / (1 + lam(alpha, mu_o)) / (1 + lam(alpha, mu_i))
    f = 1.0 if eta is None else fresnel(o_h, eta)
    return f * ggx(alpha, h[..., 2]) * g / (4 * mu_o), h, o


def albedo(mu_o, alpha, eta, correlated):
    return lobe(mu_o, alpha, eta, correlated)[0].sum() * DW


def models(r, colours, angles):
    alpha = r * r
    mus = (np.arange(64) + 0.5) / 64
    e1 = np.array([albedo(m, alpha, None, True) for m in mus])
    e1_bar = 2 * np.mean(e1 * mus)
    f_bar = 2 * np.mean(fresnel(mus, ETA) * mus)
    f_ms = f_bar * e1_bar / (1 - f_bar * (1 - e1_bar))
    mu_i = WI[..., 2]
    out = {}
    for mu_o in angles:
        spec_t, _, _ = lobe(mu_o, alpha, ETA, True)
        spec_d, h, o = lobe(mu_o, alpha, ETA, False)
        e1_o = np.interp(mu_o, mus, e1)
        e_c = spec_t.sum() * DW * (1 + f_ms * (1 - e1_o) / e1_o)
        base_t = 1 - e_c
        fo, fi = (1 - mu_o) ** 5, (1 - mu_i) ** 5
        rr = 2 * r * (WI * h).sum(-1) ** 2
        disney = ((1 - fo / 2) * (1 - fi / 2) + rr * (fo + fi + fo * fi * (rr - 1))) / np.pi
        base_d = (disney * mu_i).sum() * DW
        out[mu_o] = {c: (e_c + np.array(c) * base_t,
                         spec_d.sum() * DW + np.array(c) * base_d) for c in colours}
    return out, f_ms, e1_bar


def main():
    r = 0.5
    colours = [(0.8, 0.3, 0.2), (1.0, 1.0, 1.0)]
    angles = [float(np.cos(np.radians(a))) for a in (0, 30, 45, 60, 75, 85)]
    res, f_ms, e1_bar = models(r, colours, angles)
    print(f"roughness {r}, eta {ETA}: tessera's E1_bar = {e1_bar:.4f}, F_ms = {f_ms:.4f}")
    for c in colours:
        print(f"\nbase colour {c}")
        print("theta_o | tessera rho (R G B) | principled rho (R G B) | ratio (R G B)")
        for mu_o in angles:
            t, d = res[mu_o][c]
            print(f"{np.degrees(np.arccos(mu_o)):5.0f} | " + " ".join(f"{x:.4f}" for x in t)
                  + " | " + " ".join(f"{x:.4f}" for x in d) + " | "
                  + " ".join(f"{x:.3f}" for x in t / d))
    # The visible disc of a sphere under a uniform sky: μo has density 2μo over the disc.
    mus = (np.arange(48) + 0.5) / 48
    disc, _, _ = models(r, colours, list(mus))
    for c in colours:
        t = sum(disc[m][c][0] * 2 * m for m in mus) / len(mus)
        d = sum(disc[m][c][1] * 2 * m for m in mus) / len(mus)
        print(f"\nsphere's disc under a white sky, base {c}: tessera / principled = "
              + " ".join(f"{x:.3f}" for x in t / d))


main()
