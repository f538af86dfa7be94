/*
 * Test harness for the generated model header (built by tests/codegen/test_codegen_c.py in a tmp dir
 * against one generated model.h). Reads commands on stdin, one per line:
 *   R                              power-up: tcm_state_init, held outputs back to 0
 *   C                              print "<tcm_model_crc32> <TCM_MODEL_CRC32>" (hex)
 *   S <valid_mask> <code>... <aux>...   one tcm_step; print "<axes_mask> <out_nm>..."
 * The caller's out_nm buffer persists between steps, so held axes show their last value.
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>

#include "model.h"

int main(void)
{
    static tcm_state_t st;
    int32_t codes[TCM_N_CHANNELS + 1u] = {0};
    int32_t aux[TCM_N_AUX + 1u] = {0};
    int32_t out[TCM_N_AXES] = {0};
    char cmd[4];

    tcm_state_init(&st);
    while (scanf("%3s", cmd) == 1) {
        if (cmd[0] == 'R') {
            tcm_state_init(&st);
            for (uint32_t a = 0; a < TCM_N_AXES; ++a) {
                out[a] = 0;
            }
        } else if (cmd[0] == 'C') {
            printf("%08" PRIX32 " %08" PRIX32 "\n", tcm_model_crc32(&tcm_model),
                   (uint32_t)TCM_MODEL_CRC32);
        } else if (cmd[0] == 'S') {
            uint32_t mask;
            if (scanf("%" SCNu32, &mask) != 1) {
                return 2;
            }
            for (uint32_t c = 0; c < tcm_model.n_channels; ++c) {
                if (scanf("%" SCNd32, &codes[c]) != 1) {
                    return 2;
                }
            }
            for (uint32_t k = 0; k < tcm_model.n_aux; ++k) {
                if (scanf("%" SCNd32, &aux[k]) != 1) {
                    return 2;
                }
            }
            const uint32_t ok = tcm_step(&tcm_model, &st, codes, mask, aux, out);
            printf("%" PRIu32, ok);
            for (uint32_t a = 0; a < TCM_N_AXES; ++a) {
                printf(" %" PRId32, out[a]);
            }
            putchar('\n');
        } else {
            return 3;
        }
    }
    return 0;
}
