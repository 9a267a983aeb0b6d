/* A slow disk for make test-slow-disk: preloaded (LD_PRELOAD) into every process of a test
 * run, it delays each call that waits for the disk (fsync, fdatasync, syncfs, sync,
 * sync_file_range with a wait flag, msync with MS_SYNC) by GTBOW_FSYNC_DELAY_MS milliseconds
 * (default 200: an SD card or eMMC under load), then makes the real call. Nothing else
 * changes, so a test that passes with it does not depend on the disk's speed. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <stdlib.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

static void Delay(void) {
  static long ms = -1;
  if (ms < 0) {
    const char* s = getenv("GTBOW_FSYNC_DELAY_MS");
    ms = s != NULL ? atol(s) : 200;
    if (ms < 0) ms = 0;
  }
  struct timespec t = {ms / 1000, (ms % 1000) * 1000000L};
  const int saved = errno;
  while (nanosleep(&t, &t) != 0 && errno == EINTR) {
  }
  errno = saved;
}

#define NEXT(name) ((__typeof__(&name))dlsym(RTLD_NEXT, #name))

int fsync(int fd) {
  Delay();
  return NEXT(fsync)(fd);
}

int fdatasync(int fd) {
  Delay();
  return NEXT(fdatasync)(fd);
}

int syncfs(int fd) {
  Delay();
  return NEXT(syncfs)(fd);
}

void sync(void) {
  Delay();
  NEXT(sync)();
}

int sync_file_range(int fd, off64_t offset, off64_t nbytes, unsigned int flags) {
  if (flags & (SYNC_FILE_RANGE_WAIT_BEFORE | SYNC_FILE_RANGE_WAIT_AFTER)) Delay();
  return NEXT(sync_file_range)(fd, offset, nbytes, flags);
}

int msync(void* addr, size_t length, int flags) {
  if (flags & MS_SYNC) Delay();
  return NEXT(msync)(addr, length, flags);
}
