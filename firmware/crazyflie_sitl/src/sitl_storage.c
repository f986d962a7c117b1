/*
 * sitl_storage.c - our implementation of the firmware's storage.h (replaces hal/src/storage.c on the I2C EEPROM),
 * backed by the --params file so that a parameter stored persistently (param_logic.c: key "prm/group.name")
 * survives a restart of the process. A missing file is an empty store.
 *
 * File format (ours): "CFSITLKV1\n", then per entry: key length u8, key bytes, value length u16 little-endian,
 * value bytes. Every change rewrites the file (temporary file + rename, so a kill never leaves half a file).
 * Plain system calls only: no stdio or malloc from FreeRTOS tasks.
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "FreeRTOS.h"
#include "task.h"

#include "storage.h"

#include "sitl.h"

#define MAX_ENTRIES 128
#define MAX_KEY 255
#define MAX_VALUE 512
#define MAGIC "CFSITLKV1\n"

typedef struct {
  bool used;
  uint8_t keyLength;
  char key[MAX_KEY + 1];
  uint16_t length;
  uint8_t value[MAX_VALUE];
} entry_t;

static entry_t entries[MAX_ENTRIES];
static const char *filePath;
static bool isInit;
static uint8_t fileBuffer[MAX_ENTRIES * (1 + MAX_KEY + 2 + MAX_VALUE) + sizeof MAGIC];

static entry_t *find(const char *key) {
  for (int i = 0; i < MAX_ENTRIES; i++) {
    if (entries[i].used && strcmp(entries[i].key, key) == 0) {
      return &entries[i];
    }
  }
  return NULL;
}

void sitlStorageLoad(const char *path) {
  filePath = path;
  memset(entries, 0, sizeof entries);
  if (path == NULL) {
    return;
  }
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    return; /* missing: empty store */
  }
  ssize_t total = 0;
  for (;;) {
    ssize_t n = read(fd, fileBuffer + total, sizeof fileBuffer - (size_t)total);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    total += n;
  }
  close(fd);
  size_t magicLength = strlen(MAGIC);
  if ((size_t)total < magicLength || memcmp(fileBuffer, MAGIC, magicLength) != 0) {
    fprintf(stderr, "cf_sitl: %s is not a parameter store, starting empty\n", path);
    return;
  }
  size_t at = magicLength;
  int count = 0;
  while (at < (size_t)total && count < MAX_ENTRIES) {
    uint8_t keyLength = fileBuffer[at];
    if (keyLength == 0 || at + 1 + keyLength + 2 > (size_t)total) break;
    entry_t *e = &entries[count];
    memcpy(e->key, &fileBuffer[at + 1], keyLength);
    e->key[keyLength] = '\0';
    e->keyLength = keyLength;
    at += 1u + keyLength;
    uint16_t length = (uint16_t)(fileBuffer[at] | (fileBuffer[at + 1] << 8));
    at += 2;
    if (length > MAX_VALUE || at + length > (size_t)total) break;
    memcpy(e->value, &fileBuffer[at], length);
    e->length = length;
    e->used = true;
    at += length;
    count++;
  }
  fprintf(stderr, "cf_sitl: %d stored entries loaded from %s\n", count, path);
}

static bool save(void) {
  if (filePath == NULL) {
    return true; /* no file: the store lives as long as the process */
  }
  size_t at = 0;
  memcpy(fileBuffer, MAGIC, strlen(MAGIC));
  at += strlen(MAGIC);
  for (int i = 0; i < MAX_ENTRIES; i++) {
    const entry_t *e = &entries[i];
    if (!e->used) continue;
    fileBuffer[at++] = e->keyLength;
    memcpy(&fileBuffer[at], e->key, e->keyLength);
    at += e->keyLength;
    fileBuffer[at++] = (uint8_t)(e->length & 0xFF);
    fileBuffer[at++] = (uint8_t)(e->length >> 8);
    memcpy(&fileBuffer[at], e->value, e->length);
    at += e->length;
  }
  char tmp[4096];
  if ((size_t)snprintf(tmp, sizeof tmp, "%s.tmp", filePath) >= sizeof tmp) {
    return false;
  }
  int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) {
    sitlLog("STORAGE: cannot write %s: %s\n", tmp, strerror(errno));
    return false;
  }
  size_t done = 0;
  while (done < at) {
    ssize_t n = write(fd, fileBuffer + done, at - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      close(fd);
      return false;
    }
    done += (size_t)n;
  }
  fsync(fd);
  close(fd);
  return rename(tmp, filePath) == 0;
}

void storageInit(void) { isInit = true; }
bool storageTest(void) { return isInit; }

bool storageStore(const char *key, const void *buffer, size_t length) {
  size_t keyLength = strlen(key);
  if (keyLength == 0 || keyLength > MAX_KEY || length > MAX_VALUE) {
    return false;
  }
  bool ok;
  vTaskSuspendAll();
  entry_t *e = find(key);
  if (e == NULL) {
    for (int i = 0; i < MAX_ENTRIES && e == NULL; i++) {
      if (!entries[i].used) e = &entries[i];
    }
  }
  if (e == NULL) {
    ok = false;
  } else {
    memcpy(e->key, key, keyLength + 1);
    e->keyLength = (uint8_t)keyLength;
    memcpy(e->value, buffer, length);
    e->length = (uint16_t)length;
    e->used = true;
    ok = save();
  }
  xTaskResumeAll();
  return ok;
}

size_t storageFetch(const char *key, void *buffer, size_t length) {
  size_t result = 0;
  vTaskSuspendAll();
  const entry_t *e = find(key);
  if (e != NULL) {
    result = e->length < length ? e->length : length;
    if (buffer != NULL) memcpy(buffer, e->value, result);
  }
  xTaskResumeAll();
  return result;
}

bool storageDelete(const char *key) {
  bool ok = false;
  vTaskSuspendAll();
  entry_t *e = find(key);
  if (e != NULL) {
    e->used = false;
    ok = save();
  }
  xTaskResumeAll();
  return ok;
}

bool storageForeach(const char *prefix, storageFunc_t func) {
  static entry_t copy; /* the callback may store/fetch: call it on a copy, outside the lock */
  size_t prefixLength = strlen(prefix);
  for (int i = 0; i < MAX_ENTRIES; i++) {
    bool match = false;
    vTaskSuspendAll();
    if (entries[i].used && strncmp(entries[i].key, prefix, prefixLength) == 0) {
      copy = entries[i];
      match = true;
    }
    xTaskResumeAll();
    if (match && !func(copy.key, copy.value, copy.length)) {
      return false;
    }
  }
  return true;
}

void storagePrintStats(void) {
  int used = 0;
  for (int i = 0; i < MAX_ENTRIES; i++) used += entries[i].used;
  sitlLog("STORAGE: %d of %d entries used (%s)\n", used, MAX_ENTRIES, filePath ? filePath : "not persistent");
}

bool storageReformat(void) {
  vTaskSuspendAll();
  memset(entries, 0, sizeof entries);
  bool ok = save();
  xTaskResumeAll();
  return ok;
}
