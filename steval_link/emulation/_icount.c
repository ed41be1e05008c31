/* Instruction counter for the emulated board (steval_link.emulation.board): a unicorn code hook in C.
 *
 * unicorn calls steval_icount_hook before every instruction (uc_cb_hookcode_t). It counts, and asks unicorn to
 * stop once the count reaches the board's limit (the next event: a timer update, a UART byte, an interrupt to
 * deliver). Python registers it through unicorn's C API (ctypes) with a pointer to an icount_t it owns.
 * Without this module the board counts with a Python block hook (slower, same results at block granularity). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

typedef struct {
  uint64_t n;      /* instructions executed */
  uint64_t limit;  /* stop when n reaches this */
  int (*stop)(void *uc);
} steval_icount_t;

#if defined(_WIN32)
#define EXPORT __declspec(dllexport)
#else
#define EXPORT __attribute__((visibility("default")))
#endif

EXPORT void steval_icount_hook(void *uc, uint64_t address, uint32_t size, void *user) {
  steval_icount_t *c = (steval_icount_t *)user;
  (void)address;
  (void)size;
  if (++c->n >= c->limit) c->stop(uc);
}

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_icount",
                                    "C instruction counter hook for the emulated board", -1, NULL};

PyMODINIT_FUNC PyInit__icount(void) { return PyModule_Create(&moddef); }
