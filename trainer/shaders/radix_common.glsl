// Shared by the radix sort kernels: 64-bit keys stored as uvec2 (low word, high word), sorted
// 4 bits per pass; `shift` is a multiple of 4, so a digit never straddles the two words.
// A workgroup handles one block of RADIX_BLOCK items: RADIX_WG invocations of RADIX_PER
// consecutive items each (few invocations, few barriers: see scan_blocks.comp).
#define RADIX_BLOCK 128u
#define RADIX_PER 4u
#define RADIX_WG 32
#define RADIX_BINS 16

uint radix_digit(uvec2 key, uint shift) {
    return (shift < 32u ? (key.x >> shift) : (key.y >> (shift - 32u))) & 15u;
}

// The digit counts of up to 4 digits packed in a uvec4: 16 digits x 8 bits (a block has 128
// items, so no field overflows).
uvec4 radix_flag(uint digit) {
    uvec4 flag = uvec4(0u);
    flag[digit >> 2] = 1u << ((digit & 3u) * 8u);
    return flag;
}

uint radix_unpack(uvec4 packed, uint digit) {
    return (packed[digit >> 2] >> ((digit & 3u) * 8u)) & 255u;
}
