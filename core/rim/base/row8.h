// 8-bit storage of feature rows for the sub-map store: features that no longer train are the
// bulk of a long session's memory. A row of D floats becomes D + 1 bytes: a shared power-of-two
// exponent e, then D signed 8-bit values q, each standing for q · 2^e.
//
// Encoding picks the smallest e with round(max |x| / 2^e) ≤ 127 and rounds every value to the
// nearest multiple of 2^e (ties away from zero): the error is at most 2^(e-1), under 0.8 % of the
// row's largest magnitude. Decoding is exact (q · 2^e is a float), and re-encoding a decoded row
// gives the same bytes, so save → load → save of a store is byte-identical. A row of zeros stays
// zeros; ±inf saturates to the largest magnitude the exponent allows, NaN reads as 0, and rows
// smaller than 2^-121 lose their smallest values to zero.
#pragma once

#include <cstddef>
#include <cstdint>

namespace rim {

inline constexpr size_t Row8Bytes(int dim) { return size_t(dim) + 1; }

// Encodes `rows` rows of `dim` floats from `in` into rows · Row8Bytes(dim) bytes at `out`.
void EncodeRows8(const float* in, size_t rows, int dim, int8_t* out);
// Decodes `rows` rows of `dim` values into rows · dim floats.
void DecodeRows8(const int8_t* in, size_t rows, int dim, float* out);
// Rows read from a file, made safe in place: values of -128 (which no encoder writes) become
// -127, and exponents above the largest at which every value decodes finite (121) become that
// one. Rows that the encoder wrote from finite values are left as they are.
void SanitizeRows8(int8_t* rows, size_t count, int dim);
// The floats a row of `dim` values reads back as after a trip through 8-bit storage, in place.
void RoundRow8(float* row, int dim);

}  // namespace rim
