// os: the file operations the firmware (slots.py, boards), the tests and mpremote use, on
// POSIX calls; stat() returns the 10-tuple MicroPython ports return.
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include "py/objtuple.h"
#include "py/runtime.h"

#define CHECK(expr) do { if ((expr) < 0) { mp_raise_OSError(errno); } } while (0)

static mp_obj_t os_stat(mp_obj_t path_in) {
    struct stat st;
    const char *path = mp_obj_str_get_str(path_in);
    if (stat(path, &st) < 0) {
        mp_raise_OSError_with_filename(errno, path);
    }
    mp_obj_t items[10] = {
        mp_obj_new_int_from_uint(st.st_mode), mp_obj_new_int_from_uint(st.st_ino),
        mp_obj_new_int_from_uint(st.st_dev), mp_obj_new_int_from_uint(st.st_nlink),
        mp_obj_new_int_from_uint(st.st_uid), mp_obj_new_int_from_uint(st.st_gid),
        mp_obj_new_int_from_ll(st.st_size), mp_obj_new_int_from_ll(st.st_atime),
        mp_obj_new_int_from_ll(st.st_mtime), mp_obj_new_int_from_ll(st.st_ctime),
    };
    return mp_obj_new_tuple(10, items);
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_stat_obj, os_stat);

static mp_obj_t os_path_call(int (*fn)(const char *), mp_obj_t path_in) {
    const char *path = mp_obj_str_get_str(path_in);
    if (fn(path) < 0) {
        mp_raise_OSError_with_filename(errno, path);
    }
    return mp_const_none;
}

static int mkdir_0777(const char *p) {
    return mkdir(p, 0777);
}

static mp_obj_t os_mkdir(mp_obj_t p) {
    return os_path_call(mkdir_0777, p);
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_mkdir_obj, os_mkdir);

static mp_obj_t os_rmdir(mp_obj_t p) {
    return os_path_call(rmdir, p);
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_rmdir_obj, os_rmdir);

static mp_obj_t os_remove(mp_obj_t p) {
    return os_path_call(unlink, p);
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_remove_obj, os_remove);

static mp_obj_t os_chdir(mp_obj_t p) {
    return os_path_call(chdir, p);
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_chdir_obj, os_chdir);

static mp_obj_t os_rename(mp_obj_t a, mp_obj_t b) {
    CHECK(rename(mp_obj_str_get_str(a), mp_obj_str_get_str(b)));
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_2(os_rename_obj, os_rename);

static mp_obj_t os_getcwd(void) {
    char buf[4096];
    if (getcwd(buf, sizeof(buf)) == NULL) {
        mp_raise_OSError(errno);
    }
    return mp_obj_new_str_from_cstr(buf);
}
static MP_DEFINE_CONST_FUN_OBJ_0(os_getcwd_obj, os_getcwd);

// ilistdir(path=".") -> iterator of (name, type, inode) as on MicroPython; listdir -> names
static mp_obj_t list_dir(size_t n_args, const mp_obj_t *args, bool names_only) {
    const char *path = n_args ? mp_obj_str_get_str(args[0]) : ".";
    DIR *d = opendir(path);
    if (d == NULL) {
        mp_raise_OSError_with_filename(errno, path);
    }
    mp_obj_t list = mp_obj_new_list(0, NULL);
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        if (e->d_name[0] == '.' && (e->d_name[1] == 0 || (e->d_name[1] == '.' && e->d_name[2] == 0))) {
            continue;
        }
        mp_obj_t name = mp_obj_new_str_from_cstr(e->d_name);
        if (names_only) {
            mp_obj_list_append(list, name);
        } else {
            mp_obj_t t[3] = {name, MP_OBJ_NEW_SMALL_INT(e->d_type == DT_DIR ? 0x4000 : 0x8000),
                             mp_obj_new_int_from_uint(e->d_ino)};
            mp_obj_list_append(list, mp_obj_new_tuple(3, t));
        }
    }
    closedir(d);
    return names_only ? list : mp_getiter(list, NULL);
}

static mp_obj_t os_listdir(size_t n_args, const mp_obj_t *args) {
    return list_dir(n_args, args, true);
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(os_listdir_obj, 0, 1, os_listdir);

static mp_obj_t os_ilistdir(size_t n_args, const mp_obj_t *args) {
    return list_dir(n_args, args, false);
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(os_ilistdir_obj, 0, 1, os_ilistdir);

static mp_obj_t os_getenv(size_t n_args, const mp_obj_t *args) {
    const char *v = getenv(mp_obj_str_get_str(args[0]));
    if (v == NULL) {
        return n_args > 1 ? args[1] : mp_const_none;
    }
    return mp_obj_new_str_from_cstr(v);
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(os_getenv_obj, 1, 2, os_getenv);

// descriptor-level calls (firmware/boards/linux.py style: open/write/close)
static mp_obj_t os_open(size_t n_args, const mp_obj_t *args) {
    const char *path = mp_obj_str_get_str(args[0]);
    int fd = open(path, mp_obj_get_int(args[1]) | O_CLOEXEC, n_args > 2 ? mp_obj_get_int(args[2]) : 0777);
    if (fd < 0) {
        mp_raise_OSError_with_filename(errno, path);
    }
    return MP_OBJ_NEW_SMALL_INT(fd);
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(os_open_obj, 2, 3, os_open);

static mp_obj_t os_close(mp_obj_t fd) {
    CHECK(close(mp_obj_get_int(fd)));
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_close_obj, os_close);

static mp_obj_t os_read(mp_obj_t fd, mp_obj_t n_in) {
    mp_int_t n = mp_obj_get_int(n_in);
    vstr_t vstr;
    vstr_init_len(&vstr, n);
    ssize_t got = read(mp_obj_get_int(fd), vstr.buf, n);
    if (got < 0) {
        vstr_clear(&vstr);
        mp_raise_OSError(errno);
    }
    vstr.len = got;
    return mp_obj_new_bytes_from_vstr(&vstr);
}
static MP_DEFINE_CONST_FUN_OBJ_2(os_read_obj, os_read);

static mp_obj_t os_write(mp_obj_t fd, mp_obj_t data) {
    mp_buffer_info_t b;
    mp_get_buffer_raise(data, &b, MP_BUFFER_READ);
    ssize_t n = write(mp_obj_get_int(fd), b.buf, b.len);
    CHECK(n);
    return MP_OBJ_NEW_SMALL_INT(n);
}
static MP_DEFINE_CONST_FUN_OBJ_2(os_write_obj, os_write);

static mp_obj_t os_fsync(mp_obj_t fd) {
    CHECK(fsync(mp_obj_get_int(fd)));
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_fsync_obj, os_fsync);

static mp_obj_t os_sync(void) {
    sync();
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_0(os_sync_obj, os_sync);

static const mp_rom_map_elem_t os_globals_table[] = {
    { MP_ROM_QSTR(MP_QSTR___name__), MP_ROM_QSTR(MP_QSTR_os) },
    { MP_ROM_QSTR(MP_QSTR_sep), MP_ROM_QSTR(MP_QSTR__slash_) },
    { MP_ROM_QSTR(MP_QSTR_stat), MP_ROM_PTR(&os_stat_obj) },
    { MP_ROM_QSTR(MP_QSTR_mkdir), MP_ROM_PTR(&os_mkdir_obj) },
    { MP_ROM_QSTR(MP_QSTR_rmdir), MP_ROM_PTR(&os_rmdir_obj) },
    { MP_ROM_QSTR(MP_QSTR_remove), MP_ROM_PTR(&os_remove_obj) },
    { MP_ROM_QSTR(MP_QSTR_unlink), MP_ROM_PTR(&os_remove_obj) },
    { MP_ROM_QSTR(MP_QSTR_rename), MP_ROM_PTR(&os_rename_obj) },
    { MP_ROM_QSTR(MP_QSTR_chdir), MP_ROM_PTR(&os_chdir_obj) },
    { MP_ROM_QSTR(MP_QSTR_getcwd), MP_ROM_PTR(&os_getcwd_obj) },
    { MP_ROM_QSTR(MP_QSTR_listdir), MP_ROM_PTR(&os_listdir_obj) },
    { MP_ROM_QSTR(MP_QSTR_ilistdir), MP_ROM_PTR(&os_ilistdir_obj) },
    { MP_ROM_QSTR(MP_QSTR_getenv), MP_ROM_PTR(&os_getenv_obj) },
    { MP_ROM_QSTR(MP_QSTR_open), MP_ROM_PTR(&os_open_obj) },
    { MP_ROM_QSTR(MP_QSTR_close), MP_ROM_PTR(&os_close_obj) },
    { MP_ROM_QSTR(MP_QSTR_read), MP_ROM_PTR(&os_read_obj) },
    { MP_ROM_QSTR(MP_QSTR_write), MP_ROM_PTR(&os_write_obj) },
    { MP_ROM_QSTR(MP_QSTR_fsync), MP_ROM_PTR(&os_fsync_obj) },
    { MP_ROM_QSTR(MP_QSTR_sync), MP_ROM_PTR(&os_sync_obj) },
    { MP_ROM_QSTR(MP_QSTR_O_RDONLY), MP_ROM_INT(O_RDONLY) },
    { MP_ROM_QSTR(MP_QSTR_O_WRONLY), MP_ROM_INT(O_WRONLY) },
    { MP_ROM_QSTR(MP_QSTR_O_RDWR), MP_ROM_INT(O_RDWR) },
    { MP_ROM_QSTR(MP_QSTR_O_CREAT), MP_ROM_INT(O_CREAT) },
    { MP_ROM_QSTR(MP_QSTR_O_TRUNC), MP_ROM_INT(O_TRUNC) },
    { MP_ROM_QSTR(MP_QSTR_O_APPEND), MP_ROM_INT(O_APPEND) },
    { MP_ROM_QSTR(MP_QSTR_O_EXCL), MP_ROM_INT(O_EXCL) },
};
static MP_DEFINE_CONST_DICT(os_globals, os_globals_table);

const mp_obj_module_t mp_module_os = {
    .base = { &mp_type_module },
    .globals = (mp_obj_dict_t *)&os_globals,
};
MP_REGISTER_EXTENSIBLE_MODULE(MP_QSTR_os, mp_module_os);
