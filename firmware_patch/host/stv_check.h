/* The host tests' check: CHECK(cond) counts every check and reports a failed one on stderr (file:line: the
 * condition) without stopping; a selftest ends with checks_failed(). One per test program. */
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

/* At the end of a selftest: 1 after "N of M checks failed" on stderr, 0 when every check passed. */
static inline int checks_failed(void) {
  if (!failures) return 0;
  fprintf(stderr, "%d of %d checks failed\n", failures, checks);
  return 1;
}

#endif
