/* Instantiates, initializes, steps, terminates and frees an FMI 2.0 co-simulation FMU many
   times through dlopen(), counting the allocations made through the callbacks: a leak shows
   as allocations without a matching free (and, built with -fsanitize=address, as a
   LeakSanitizer report). Usage: fmu_leak_driver LIB GUID N */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"

static long live = 0, total = 0;

static void* count_alloc(size_t n, size_t size) {
    void* p = calloc(n, size);
    if (p) { ++live; ++total; }
    return p;
}

static void count_free(void* p) {
    if (p) --live;
    free(p);
}

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    (void)env; (void)name; (void)category; (void)message;
    if (status > fmi2Warning) fprintf(stderr, "FMU error: %s\n", message);
}

#define LOAD(name) name##TYPE* name = (name##TYPE*)dlsym(lib, #name); \
    if (!name) { fprintf(stderr, "missing %s\n", #name); return 2; }

int main(int argc, char** argv) {
    void* lib;
    long i, n;
    fmi2CallbackFunctions cb = {logger, count_alloc, count_free, NULL, NULL};
    if (argc != 4) return 2;
    n = atol(argv[3]);
    lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 2; }
    {
        LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
        LOAD(fmi2ExitInitializationMode) LOAD(fmi2DoStep) LOAD(fmi2Terminate)
        LOAD(fmi2FreeInstance)
        for (i = 0; i < n; ++i) {
            fmi2Component c = fmi2Instantiate("leak", fmi2CoSimulation, argv[2], "", &cb,
                                              fmi2False, fmi2False);
            if (!c) { fprintf(stderr, "instantiation %ld failed\n", i); return 1; }
            if (fmi2SetupExperiment(c, fmi2False, 0, 0, fmi2False, 0) != fmi2OK ||
                fmi2EnterInitializationMode(c) != fmi2OK ||
                fmi2ExitInitializationMode(c) != fmi2OK ||
                fmi2DoStep(c, 0, 1e-3, fmi2True) != fmi2OK || fmi2Terminate(c) != fmi2OK) {
                fprintf(stderr, "run %ld failed\n", i);
                return 1;
            }
            fmi2FreeInstance(c);
        }
    }
    dlclose(lib);
    printf("instances %ld allocations %ld live %ld\n", n, total, live);
    return live == 0 ? 0 : 1;
}
