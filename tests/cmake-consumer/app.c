/* Links libsie through its CMake package and registers a small cloud onto a shifted copy. */
#include <sie.h>

#include <stdio.h>
#include <string.h>

int main(void) {
    enum { SIDE = 12, N = SIDE * SIDE * 3 };
    static float source[N][3], target[N][3];
    /* Three orthogonal 12x12 grids (a box corner) with 5 cm spacing; target = source + 2 cm in x. */
    int n = 0;
    for (int face = 0; face < 3; face++) {
        for (int i = 0; i < SIDE; i++) {
            for (int j = 0; j < SIDE; j++, n++) {
                float u = 0.05f * (float)i, v = 0.05f * (float)j;
                float p[3] = {0.0f, 0.0f, 0.0f};
                p[(face + 1) % 3] = u;
                p[(face + 2) % 3] = v;
                memcpy(source[n], p, sizeof p);
                target[n][0] = p[0] + 0.02f;
                target[n][1] = p[1];
                target[n][2] = p[2];
            }
        }
    }
    if (sie_version_number() != SIE_VERSION_NUMBER) {
        fprintf(stderr, "header %s, library %s\n", SIE_VERSION_STRING, sie_version_string());
        return 1;
    }
    sie_context *ctx = sie_context_new();
    double T[16];
    sie_status status = sie_context_register(ctx, &source[0][0], N, 0, &target[0][0], N, 0, NULL, T);
    if (status != SIE_STATUS_OK) {
        fprintf(stderr, "sie: %s\n", sie_context_last_error(ctx));
        sie_context_free(ctx);
        return 1;
    }
    sie_context_free(ctx);
    printf("libsie %s: translation %.4f %.4f %.4f\n", sie_version_string(), T[3], T[7], T[11]);
    /* The translation must come out as 2 cm along x. */
    return (T[3] > 0.019 && T[3] < 0.021 && T[7] > -0.001 && T[7] < 0.001 && T[11] > -0.001 && T[11] < 0.001)
               ? 0
               : 1;
}
