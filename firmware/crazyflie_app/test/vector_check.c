/*
 * vector_check.c - the C side of the packet vectors shared with the ground station.
 *
 *   vector_check packet_vectors.txt
 *
 * The vector file is written by the Python encoder (groundstation/backends/crtp_wire.py, kept equal to it by
 * tests/backends/test_crtp_wire.py). For each `command` and `claim` line this decodes the hex as the module would
 * and checks the status and fields; for each `state` and `identity` line it encodes the fields as the module
 * would and checks the hex, and prints its own encoding (`state-c hex=...`, `identity-c hex=...`) so the Python
 * test can decode it back. Exit status 1 on mismatch.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "motor_protocol.h"

static int failures = 0;
static int line_no = 0;

static void fail(const char *what) {
  fprintf(stderr, "line %d: %s\n", line_no, what);
  failures++;
}

/* The value of `key=` in a record, or NULL. */
static const char *field(const char *line, const char *key) {
  const size_t n = strlen(key);
  for (const char *p = line; (p = strstr(p, key)) != NULL; p += n) {
    if ((p == line || p[-1] == ' ') && p[n] == '=') {
      return p + n + 1;
    }
  }
  return NULL;
}

static long number(const char *line, const char *key) {
  const char *v = field(line, key);
  if (v == NULL) {
    fail(key);
    return 0;
  }
  return strtol(v, NULL, 0);
}

static size_t hex_bytes(const char *line, uint8_t *out, size_t cap) {
  const char *v = field(line, "hex");
  size_t n = 0;
  if (v == NULL) {
    fail("no hex");
    return 0;
  }
  while (n < cap && v[0] != '\0' && v[0] != ' ' && v[0] != '\n' && v[1] != '\0') {
    char byte[3] = {v[0], v[1], '\0'};
    out[n++] = (uint8_t)strtoul(byte, NULL, 16);
    v += 2;
  }
  return n;
}

/* Comma-separated numbers after `key=` into out[count]. */
static void list(const char *line, const char *key, double *out, int count) {
  const char *v = field(line, key);
  if (v == NULL) {
    fail(key);
    return;
  }
  for (int i = 0; i < count; i++) {
    char *end;
    out[i] = strtod(v, &end);
    v = end + (*end == ',' ? 1 : 0);
  }
}

static const char *status_name(mp_status_t s) {
  switch (s) {
    case MP_OK: return "OK";
    case MP_BAD_LENGTH: return "BAD_LENGTH";
    case MP_BAD_KIND: return "BAD_KIND";
    case MP_NOT_FOR_US: return "NOT_FOR_US";
  }
  return "?";
}

static void check_command(const char *line) {
  uint8_t buf[64];
  const size_t n = hex_bytes(line, buf, sizeof buf);
  mp_command_t cmd;
  memset(&cmd, 0, sizeof cmd);
  const mp_status_t s = mp_decode_command(buf, n, (uint8_t)number(line, "slot"), &cmd);
  const char *want = field(line, "status");
  if (want == NULL || strncmp(want, status_name(s), strlen(status_name(s))) != 0) {
    fail("status differs");
    return;
  }
  if (s != MP_OK) {
    return;
  }
  double counts[4];
  list(line, "counts", counts, 4);
  if (cmd.sequence != number(line, "seq") || cmd.armed != (number(line, "armed") != 0) ||
      cmd.token != number(line, "token")) {
    fail("sequence, armed flag or token differs");
  }
  for (int q = 0; q < 4; q++) {
    if (cmd.counts[q] != (uint16_t)counts[q]) {
      fail("counts differ");
    }
  }
}

static void print_hex(const char *kind, const uint8_t *bytes, size_t n) {
  printf("%s-c line=%d hex=", kind, line_no);
  for (size_t i = 0; i < n; i++) {
    printf("%02x", bytes[i]);
  }
  printf("\n");
}

static void check_state(const char *line) {
  mp_state_t st;
  double counts[4], gyro[3];
  memset(&st, 0, sizeof st);
  list(line, "counts", counts, 4);
  list(line, "gyro", gyro, 3);
  st.flags = (uint8_t)number(line, "flags");
  st.sequence = (uint16_t)number(line, "seq");
  for (int q = 0; q < 4; q++) {
    st.counts[q] = (uint16_t)counts[q];
  }
  for (int k = 0; k < 3; k++) {
    st.gyro[k] = (float)gyro[k];
  }
  st.battery_mv = (uint16_t)number(line, "battery_mv");
  st.received = (uint16_t)number(line, "received");
  st.dropped = (uint16_t)number(line, "dropped");
  uint8_t mine[MP_STATE_SIZE], theirs[64];
  const size_t n = mp_encode_state(&st, mine, sizeof mine);
  const size_t m = hex_bytes(line, theirs, sizeof theirs);
  if (n != m || memcmp(mine, theirs, n) != 0) {
    fail("state encoding differs");
  }
  print_hex("state", mine, n);
}

static void check_claim(const char *line) {
  uint8_t buf[64];
  const size_t n = hex_bytes(line, buf, sizeof buf);
  uint32_t session = 0;
  const bool valid = mp_decode_claim(buf, n, &session);
  if (valid != (number(line, "valid") != 0) || (valid && session != (uint32_t)strtoul(field(line, "session"),
                                                                                     NULL, 0))) {
    fail("claim differs");
  }
}

static void check_identity(const char *line) {
  mp_identity_t id;
  double uid[3], acc[3];
  memset(&id, 0, sizeof id);
  list(line, "uid", uid, 3);
  list(line, "acc_mg", acc, 3);
  id.flags = (uint8_t)number(line, "flags");
  id.token = (uint8_t)number(line, "token");
  id.session = (uint32_t)strtoul(field(line, "session"), NULL, 0);
  for (int k = 0; k < 3; k++) {
    id.uid[k] = (uint32_t)uid[k];
    id.acc_mg[k] = (int16_t)acc[k];
  }
  uint8_t mine[MP_IDENTITY_SIZE], theirs[64];
  const size_t n = mp_encode_identity(&id, mine, sizeof mine);
  const size_t m = hex_bytes(line, theirs, sizeof theirs);
  if (n != m || memcmp(mine, theirs, n) != 0) {
    fail("identity encoding differs");
  }
  print_hex("identity", mine, n);
}

int main(int argc, char **argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: vector_check packet_vectors.txt\n");
    return 2;
  }
  FILE *f = fopen(argv[1], "r");
  if (f == NULL) {
    perror(argv[1]);
    return 2;
  }
  char line[512];
  int commands = 0, states = 0;
  while (fgets(line, sizeof line, f) != NULL) {
    line_no++;
    if (strncmp(line, "command ", 8) == 0) {
      check_command(line);
      commands++;
    } else if (strncmp(line, "state ", 6) == 0) {
      check_state(line);
      states++;
    } else if (strncmp(line, "claim ", 6) == 0) {
      check_claim(line);
      commands++;
    } else if (strncmp(line, "identity ", 9) == 0) {
      check_identity(line);
      states++;
    }
  }
  fclose(f);
  fprintf(stderr, "%d command and %d state vectors, %d failures\n", commands, states, failures);
  return failures == 0 && commands > 0 && states > 0 ? 0 : 1;
}
