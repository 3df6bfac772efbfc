// Thin-film interference (Belcour & Barla 2017, "A Practical Extension to Microfacet Theory for
// the Modeling of Varying Iridescence") as Cycles 4.5 applies it to the Principled BSDF's
// dielectric lobes: the Airy sum of the film's reflections to third order, integrated over the
// spectrum in Fourier space with the paper's Gaussian fit of the CIE XYZ curves (illuminant E),
// then taken to linear Rec.709 with the D65 white point multiplied in (Cycles' shortcut for the
// chromatic adaptation). Blender 4.5 has no thin film on its metals.
#pragma once
#include "scene/microfacet.h"

namespace pl {

// Below this thickness (nm) there is no film (Cycles' THINFILM_THICKNESS_CUTOFF).
constexpr float kThinFilmCutoff = 0.1f;

// Reflectances of a dielectric interface for s- and p-polarised light, with the phase shift
// on reflection (0 or pi) and the cosine of the refracted direction (negative: across the
// interface). eta = n_transmitted / n_incident. Total internal reflection: (1, 1), phases 0.
struct PolarizedFresnel {
  float rs = 1.0f, rp = 1.0f;
  float phi_s = 0.0f, phi_p = 0.0f;
  float cos_t = 0.0f;
  bool tir = true;
};
inline PolarizedFresnel fresnel_polarized(float cos_i, float eta) {
  PolarizedFresnel f;
  const float e2 = eta * eta - (1.0f - cos_i * cos_i);  // (eta cos_t)^2 by Snell
  if (!(e2 > 0.0f)) return f;
  cos_i = std::fabs(cos_i);
  f.tir = false;
  f.cos_t = -std::sqrt(e2) / eta;
  const float as = (cos_i + eta * f.cos_t) / (cos_i - eta * f.cos_t);
  const float ap = (f.cos_t + eta * cos_i) / (eta * cos_i - f.cos_t);
  f.phi_s = as < 0.0f ? kPi : 0.0f;
  f.phi_p = ap < 0.0f ? kPi : 0.0f;
  f.rs = as * as;
  f.rp = ap * ap;
  return f;
}

// The Fourier transform of the XYZ sensitivities at optical path difference opd (nm), shifted
// by a phase: the paper's fit (three Gaussians, a fourth term for X's blue lobe), normalised
// so that a flat spectrum of 1 gives Y = 1. Held unshifted, as each term's amplitude (its
// Gaussian envelope) and the cosine and sine of its phase, so that the two polarisations
// (which differ only by the shift) share them: cos(a + s) = cos a cos s - sin a sin s.
struct ThinFilmSpectrum {
  float amp[4], c[4], s[4];
  Vec3 at(float cos_shift, float sin_shift) const {
    float v[4];
    for (int i = 0; i < 4; ++i) v[i] = amp[i] * (c[i] * cos_shift - s[i] * sin_shift);
    return Vec3{v[0] + v[3], v[1], v[2]};
  }
};
// The spectra at 1, 2 and 3 times opd (the Airy sum's three path differences): four exp and
// four sincos for all three, the envelopes exp(-m^2 x) as powers of m = 1's and the phases by
// the double- and triple-angle formulas (the direct form's values within float rounding; the
// paper's and Cycles' code call exp and cos for each of the 24 terms).
inline void thin_film_spectra(float opd, ThinFilmSpectrum spec[3]) {
  const float phase = 2.0f * kPi * opd * 1e-9f;
  const float p2 = phase * phase;
  // kVal sqrt(2 pi kVar) for the Gaussians, over the normalisation 1.0685e-7.
  constexpr float kAmp[4] = {5.4856e-13f * 1.6490109e5f / 1.0685e-7f, 4.4201e-13f * 2.4179025e5f / 1.0685e-7f,
                             5.2481e-13f * 2.0382603e5f / 1.0685e-7f, 1.64408e-8f / 1.0685e-7f};
  constexpr float kPos[4] = {1.6810e+06f, 1.7953e+06f, 2.2084e+06f, 2.2399e+06f};
  constexpr float kVar[4] = {4.3278e+09f, 9.3046e+09f, 6.6121e+09f, 4.5282e+09f};
  for (int i = 0; i < 4; ++i) {
    const float e = std::exp(-p2 * kVar[i]), e4 = (e * e) * (e * e);
    spec[0].amp[i] = kAmp[i] * e;
    spec[1].amp[i] = kAmp[i] * e4;
    spec[2].amp[i] = kAmp[i] * (e4 * e4 * e);
    const float c = std::cos(kPos[i] * phase), s = std::sin(kPos[i] * phase);
    const float c2 = c * c - s * s, s2 = 2.0f * s * c;
    spec[0].c[i] = c;
    spec[0].s[i] = s;
    spec[1].c[i] = c2;
    spec[1].s[i] = s2;
    spec[2].c[i] = c2 * c - s2 * s;
    spec[2].s[i] = s2 * c + c2 * s;
  }
}
inline Vec3 thin_film_sensitivity(float opd, float shift) {
  ThinFilmSpectrum spec[3];
  thin_film_spectra(opd, spec);
  return spec[0].at(std::cos(shift), std::sin(shift));
}

// The paper's Airy summation for one polarisation (its equation 10), truncated after the third
// path difference as Cycles does; spec: thin_film_spectra of the path difference, phi the
// phase shift (m phi at the m-th).
inline Vec3 thin_film_airy(float t121, float r12, float r23, const ThinFilmSpectrum spec[3], float phi) {
  if (r23 == 1.0f) return Vec3(1.0f);
  const float r123 = r12 * r23;
  const float sqrt_r123 = std::sqrt(r123);
  const float rs = t121 * t121 * r23 / (1.0f - r123);
  Vec3 r(r12 + rs);
  float cm = rs - t121;
  const float c1 = std::cos(phi), s1 = std::sin(phi);
  float cs = c1, sn = s1;  // cos and sin of m phi
  for (int m = 1; m < 4; ++m) {
    cm *= sqrt_r123;
    r += spec[m - 1].at(cs, sn) * (2.0f * cm);
    const float c_next = cs * c1 - sn * s1;
    sn = sn * c1 + cs * s1;
    cs = c_next;
  }
  return r;
}

// Reflectance (linear Rec.709) from a medium of IOR eta1 onto a film of IOR eta2 and
// `thickness` nm over a base of IOR eta3, at cos_1 to the normal.
inline Vec3 fresnel_thin_film(float eta1, float eta2, float eta3, float cos_1, float thickness) {
  if (thickness < 30.0f) {  // too thin for the wave model: fade the film out
    const float t = clampf(thickness / 30.0f, 0.0f, 1.0f);
    eta2 = eta1 + (eta2 - eta1) * (t * t * (3.0f - 2.0f * t));
  }
  const PolarizedFresnel f12 = fresnel_polarized(cos_1, eta2 / eta1);
  if (f12.tir) return Vec3(1.0f);
  const float opd = -2.0f * eta2 * thickness * f12.cos_t;
  const PolarizedFresnel f23 = fresnel_polarized(-f12.cos_t, eta3 / eta2);
  if (f23.tir) return Vec3(1.0f);
  ThinFilmSpectrum spec[3];
  thin_film_spectra(opd, spec);
  const Vec3 xyz = (thin_film_airy(1.0f - f12.rs, f12.rs, f23.rs, spec, kPi - f12.phi_s + f23.phi_s) +
                    thin_film_airy(1.0f - f12.rp, f12.rp, f23.rp, spec, kPi - f12.phi_p + f23.phi_p)) *
                   0.5f;
  // Illuminant E to the D65 white of linear Rec.709, then its XYZ -> RGB (sRGB's matrix).
  const Vec3 w = xyz * Vec3{0.95047f, 1.0f, 1.08883f};
  const Vec3 rgb{3.2404542f * w.x - 1.5371385f * w.y - 0.4985314f * w.z,
                 -0.9692660f * w.x + 1.8760108f * w.y + 0.0415560f * w.z,
                 0.0556434f * w.x - 0.2040259f * w.y + 1.0572252f * w.z};
  return vmin(vmax(rgb, Vec3(0.0f)), Vec3(1.0f));
}

// The Principled BSDF's dielectric Fresnel with a film, as Cycles: the film's reflectance from
// air (eta_film, eta_base relative to the outside), then F0 tinting per channel: scaled by
// f0 / F0(eta_base), fully where the reflectance is at F0 and not at all where it reaches 1.
// Out of line: kept off the hot path of the lobes without a film.
[[gnu::noinline]] inline Vec3 thin_film_dielectric(float cos_i, float eta_film, float eta_base, float thickness,
                                                   Vec3 f0) {
  Vec3 F = fresnel_thin_film(1.0f, eta_film, eta_base, cos_i, thickness);
  const float r = (eta_base - 1.0f) / (eta_base + 1.0f), F0 = r * r;
  if (F0 > 1e-5f && !(F.x == 1.0f && F.y == 1.0f && F.z == 1.0f)) {
    auto tint = [&](float f, float f0c) {
      const float s = clampf((f - 1.0f) / (F0 - 1.0f), 0.0f, 1.0f);
      return f * (1.0f + (f0c / F0 - 1.0f) * s);
    };
    F = {tint(F.x, f0.x), tint(F.y, f0.y), tint(F.z, f0.z)};
  }
  return F;
}

}  // namespace pl
