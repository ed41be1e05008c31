/* The host tests' check: CHECK(cond) counts every check and reports a failed one on stderr (file:line: the
 * condition) without stopping; a test's selftest reads `failures` and `checks` at the end. One per test program. */
#ifndef STV_CHECK_H
#define STV_CHECK_H

#include <stdio.h>

static int checks, failures;
#define CHECK(cond)                                                             \
  do {                                                                          \
    checks++;                                                                   \
    if (!(cond)) {                                                              \
      failures++;                                                               \
      fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); \
    }                                                                           \
  } while (0)

#endif
