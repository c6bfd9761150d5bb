/* emlearn comparison image: the C that emlearn generates for MLPs of the same
 * layer sizes as phi (6-25-40-40-H) and rho (H-40-40-40-1); the benchmark calls
 * the two regress functions in the instruction-counting emulator (kept out of
 * line through a volatile table). */
#include "eml_phi.h"
#include "eml_rho.h"

typedef int32_t (*regress_fn)(const float *, int32_t, float *, int32_t);
regress_fn volatile ns2_eml_table[2] = {eml_phi_regress, eml_rho_regress};

int main(void)
{
    static float in[64], out[64];
    return (int)(ns2_eml_table[0](in, 6, out, 20) + ns2_eml_table[1](in, 20, out, 1));
}
