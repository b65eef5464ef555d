// ARM semihosting calls (QEMU -semihosting): the host's files stand in for the board's flash,
// the host's stderr for a debug console, and the exit call ends the emulator with a status.
#ifndef MPS2_SEMIHOST_H
#define MPS2_SEMIHOST_H
#include <stddef.h>
#include <stdint.h>

#define SH_OPEN_R (1)    // "rb"
#define SH_OPEN_W (5)    // "wb"
#define SH_OPEN_RW (3)   // "r+b"
#define SH_OPEN_WR (7)   // "w+b"
#define SH_OPEN_A (9)    // "ab"
#define SH_OPEN_AR (11)  // "a+b"

int sh_open(const char *path, int mode);
int sh_close(int fd);
int sh_write(int fd, const void *buf, size_t len);  // bytes written, -1 on error
int sh_read(int fd, void *buf, size_t len);         // bytes read, -1 on error
int sh_seek(int fd, size_t pos);
int sh_flen(int fd);
int sh_remove(const char *path);
int sh_rename(const char *from, const char *to);
int sh_errno(void);
int sh_cmdline(char *buf, size_t len);
void sh_stderr(const char *buf, size_t len);
void sh_exit(int status) __attribute__((noreturn));
#endif
