// A file object on a POSIX descriptor (file.c); also the base of the port's sockets.
#ifndef LINUX32_FDFILE_H
#define LINUX32_FDFILE_H
#include "py/obj.h"

typedef struct _fdfile_t {
    mp_obj_base_t base;
    int fd;
} fdfile_t;

extern const mp_obj_type_t mp_type_fdfile_fileio;
extern const mp_obj_type_t mp_type_fdfile_textio;
mp_obj_t fdfile_new(int fd, bool binary);
extern const struct _mp_stream_p_t fdfile_binary_stream_p;
#endif
