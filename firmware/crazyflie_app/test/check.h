/*
 * check.h - a minimal assertion harness for the host tests: every failed CHECK prints its place and the run
 * exits non-zero.
 */
#ifndef CHECK_H_
#define CHECK_H_

#include <stdio.h>

extern int check_failures;
extern int check_count;

#define CHECK(cond)                                                       \
  do {                                                                    \
    check_count++;                                                        \
    if (!(cond)) {                                                        \
      check_failures++;                                                   \
      fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
    }                                                                     \
  } while (0)

#define CHECK_EQ_INT(a, b)                                                                              \
  do {                                                                                                  \
    check_count++;                                                                                      \
    long long va_ = (long long)(a), vb_ = (long long)(b);                                               \
    if (va_ != vb_) {                                                                                   \
      check_failures++;                                                                                 \
      fprintf(stderr, "%s:%d: CHECK failed: %s == %s (%lld != %lld)\n", __FILE__, __LINE__, #a, #b, va_, vb_); \
    }                                                                                                   \
  } while (0)

#endif /* CHECK_H_ */
