// Shared by the radix sort kernels: 64-bit keys stored as uvec2 (low word, high word), sorted
// 4 bits per pass; `shift` is a multiple of 4, so a digit never straddles the two words.
#define RADIX_WG 128
#define RADIX_BINS 16

uint radix_digit(uvec2 key, uint shift) {
    return (shift < 32u ? (key.x >> shift) : (key.y >> (shift - 32u))) & 15u;
}
