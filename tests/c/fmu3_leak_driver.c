/* Instantiates, initializes, steps, terminates and frees an FMI 3.0 co-simulation FMU many
   times through dlopen(). FMI 3.0 passes no allocator, so the leak check is LeakSanitizer's
   (built with -fsanitize=address, which intercepts the FMU's calloc and free).
   Usage: fmu3_leak_driver LIB TOKEN N */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi3Functions.h"

static void logger(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                   fmi3String message) {
    (void)env; (void)category;
    if (status > fmi3Warning) fprintf(stderr, "FMU error: %s\n", message);
}

#define LOAD(name) name##TYPE* name = (name##TYPE*)dlsym(lib, #name); \
    if (!name) { fprintf(stderr, "missing %s\n", #name); return 2; }

int main(int argc, char** argv) {
    void* lib;
    long i, n;
    if (argc != 4) return 2;
    n = atol(argv[3]);
    lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 2; }
    {
        LOAD(fmi3InstantiateCoSimulation) LOAD(fmi3EnterInitializationMode)
        LOAD(fmi3ExitInitializationMode) LOAD(fmi3DoStep) LOAD(fmi3Terminate)
        LOAD(fmi3FreeInstance)
        for (i = 0; i < n; ++i) {
            fmi3Boolean event, terminate, early;
            fmi3Float64 last;
            fmi3Instance c = fmi3InstantiateCoSimulation("leak", argv[2], "", fmi3False,
                                                         fmi3False, fmi3False, fmi3False, NULL,
                                                         0, NULL, logger, NULL);
            if (!c) { fprintf(stderr, "instantiation %ld failed\n", i); return 1; }
            if (fmi3EnterInitializationMode(c, fmi3False, 0, 0, fmi3False, 0) != fmi3OK ||
                fmi3ExitInitializationMode(c) != fmi3OK ||
                fmi3DoStep(c, 0, 1e-3, fmi3True, &event, &terminate, &early, &last) != fmi3OK
                || fmi3Terminate(c) != fmi3OK || terminate || last != 1e-3) {
                fprintf(stderr, "run %ld failed\n", i);
                return 1;
            }
            fmi3FreeInstance(c);
        }
    }
    dlclose(lib);
    printf("instances %ld\n", n);
    return 0;
}
