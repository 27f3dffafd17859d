#pragma once
// N pixels of a row at a time in GCC's vector extensions, for the tile
// loops of the fitted billboards (the display compositor and the fit's
// rasterizer): 4 lanes (SSE on x86-64, NEON on arm64, without asking for
// either) or 8 (AVX2, in functions compiled for it and chosen at run time
// where the processor has it). Internal to reconstruct/; a unit including
// it is compiled with -Wno-psabi (the helpers take and return vectors, and
// are always inlined into the function compiled for AVX2).

#include <bit>
#include <cstdint>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace s2r::simd {

template <int N>
struct VectorTypes;
template <>
struct VectorTypes<4> {
  typedef float f __attribute__((vector_size(16)));
  typedef int32_t i __attribute__((vector_size(16)));
};
template <>
struct VectorTypes<8> {
  typedef float f __attribute__((vector_size(32)));
  typedef int32_t i __attribute__((vector_size(32)));
};

template <int N>
struct Lanes {
  using f = typename VectorTypes<N>::f;
  using i = typename VectorTypes<N>::i;
  [[gnu::always_inline]] static inline f all(float s) {
    f v;
    for (int k = 0; k < N; ++k) v[k] = s;
    return v;
  }
  [[gnu::always_inline]] static inline i all_i(int32_t s) {
    i v;
    for (int k = 0; k < N; ++k) v[k] = s;
    return v;
  }
  [[gnu::always_inline]] static inline f iota(float start) {
    f v;
    for (int k = 0; k < N; ++k) v[k] = start + float(k);
    return v;
  }
  // exp(x) for x in [-80, 0]: 2^t as 2^floor(t) times the degree-6
  // polynomial of splat_fit's fast_exp, the same operations in the same order.
  [[gnu::always_inline]] static inline f exp(f x) {
    x = x < all(-80.f) ? all(-80.f) : x;
    const f t = x * 1.4426950408889634f;
    i ti = __builtin_convertvector(t, i);          // toward zero
    ti += (t < __builtin_convertvector(ti, f));    // -1 where that rounded up: floor
    const f fr = t - __builtin_convertvector(ti, f);
    const f p = 1.f + fr * (0.69314718f + fr * (0.24022651f + fr * (0.05550411f + fr * (0.00961813f + fr * (0.00133336f + fr * 0.00015404f)))));
    const i bits = (ti + 127) << 23;
    return p * std::bit_cast<f>(bits);
  }
  // a where the mask is set, else 0.
  [[gnu::always_inline]] static inline f select(i mask, f a) { return std::bit_cast<f>(std::bit_cast<i>(a) & mask); }
  // a where the mask is set, else b.
  [[gnu::always_inline]] static inline f blend(i mask, f a, f b) {
    return std::bit_cast<f>((std::bit_cast<i>(a) & mask) | (std::bit_cast<i>(b) & ~mask));
  }
  [[gnu::always_inline]] static inline bool all_set(i m) {
    int32_t x = -1;
    for (int k = 0; k < N; ++k) x &= m[k];
    return x != 0;
  }
  [[gnu::always_inline]] static inline bool any_set(i m) {
    int32_t x = 0;
    for (int k = 0; k < N; ++k) x |= m[k];
    return x != 0;
  }
  [[gnu::always_inline]] static inline float sum(f v) {
    float s = 0;
    for (int k = 0; k < N; ++k) s += v[k];
    return s;
  }
  [[gnu::always_inline]] static inline f load(const float* p) {
    f v;
    __builtin_memcpy(&v, p, sizeof v);
    return v;
  }
  [[gnu::always_inline]] static inline i load(const int32_t* p) {
    i v;
    __builtin_memcpy(&v, p, sizeof v);
    return v;
  }
  [[gnu::always_inline]] static inline void store(float* p, f v) { __builtin_memcpy(p, &v, sizeof v); }
  [[gnu::always_inline]] static inline void store(int32_t* p, i v) { __builtin_memcpy(p, &v, sizeof v); }
};

#if defined(__x86_64__)
// On x86-64 a mask's lanes read at once (the lanes' masks are 0 or -1).
template <>
[[gnu::always_inline]] inline bool Lanes<4>::any_set(i m) {
  return _mm_movemask_ps(std::bit_cast<__m128>(m)) != 0;
}
template <>
[[gnu::always_inline]] inline bool Lanes<4>::all_set(i m) {
  return _mm_movemask_ps(std::bit_cast<__m128>(m)) == 0xf;
}
template <>
[[gnu::target("avx2")]] inline bool Lanes<8>::any_set(i m) {
  return _mm256_movemask_ps(std::bit_cast<__m256>(m)) != 0;
}
template <>
[[gnu::target("avx2")]] inline bool Lanes<8>::all_set(i m) {
  return _mm256_movemask_ps(std::bit_cast<__m256>(m)) == 0xff;
}
#endif

// Whether this processor runs the 8-lane (AVX2) functions.
inline bool has_avx2() {
#if defined(__x86_64__)
  static const bool avx2 = __builtin_cpu_supports("avx2");
  return avx2;
#else
  return false;
#endif
}

}  // namespace s2r::simd
