// Entry point of tcomp's 32-bit Linux MicroPython: the unix port's command line, reduced to what
// the tests, the HIL rig and mpremote use.
//   micropython [-X heapsize=N[K|M]] [-O<n>] [-c CMD | -m MODULE | SCRIPT] [ARGS...]
// No script: the REPL (friendly and raw, as on a board; mpremote drives the raw one) when stdin
// is a terminal, else the program read from stdin.
// sys.path: "" (the script's folder when running a script), the MICROPYPATH entries (default
// ".frozen"), then the port's lib folder (json.py), found next to the executable.
#include <errno.h>
#include <libgen.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "py/builtin.h"
#include "py/compile.h"
#include "py/cstack.h"
#include "py/gc.h"
#include "py/mperrno.h"
#include "py/mphal.h"
#include "py/runtime.h"
#include "py/stackctrl.h"
#include "shared/runtime/gchelper.h"
#include "shared/runtime/pyexec.h"

#define DEFAULT_HEAP (1024 * 1024)

static int usage(const char *prog) {
    fprintf(stderr, "usage: %s [-X heapsize=N[K|M]] [-O<n>] [-c cmd | -m module | file] [args...]\n", prog);
    return 2;
}

// Exit status of an uncaught exception: SystemExit's code, else 1 after printing it to stderr.
static int uncaught(mp_obj_t exc) {
    if (mp_obj_is_subclass_fast(MP_OBJ_FROM_PTR(mp_obj_get_type(exc)), MP_OBJ_FROM_PTR(&mp_type_SystemExit))) {
        mp_obj_t val = mp_obj_exception_get_value(exc);
        if (val == mp_const_none) {
            return 0;
        }
        mp_int_t code;
        if (mp_obj_get_int_maybe(val, &code)) {
            return code & 0xff;
        }
        mp_obj_print_helper(&mp_stderr_print, val, PRINT_STR);
        mp_print_str(&mp_stderr_print, "\n");
        return 1;
    }
    mp_obj_print_exception(&mp_stderr_print, exc);
    return 1;
}

enum { SRC_STR, SRC_FILE, SRC_FD };

static int execute(int kind, const char *src) {
    nlr_buf_t nlr;
    if (nlr_push(&nlr) == 0) {
        mp_lexer_t *lex;
        if (kind == SRC_STR) {
            lex = mp_lexer_new_from_str_len(MP_QSTR__lt_stdin_gt_, src, strlen(src), false);
        } else if (kind == SRC_FILE) {
            lex = mp_lexer_new_from_file(qstr_from_str(src));
        } else {
            lex = mp_lexer_new_from_fd(MP_QSTR__lt_stdin_gt_, 0, false);
        }
        qstr source_name = lex->source_name;
        #if MICROPY_MODULE___FILE__
        if (kind == SRC_FILE) {
            mp_store_global(MP_QSTR___file__, MP_OBJ_NEW_QSTR(source_name));
        }
        #endif
        mp_parse_tree_t tree = mp_parse(lex, MP_PARSE_FILE_INPUT);
        mp_obj_t fun = mp_compile(&tree, source_name, false);
        mp_call_function_0(fun);
        nlr_pop();
        return 0;
    }
    return uncaught(MP_OBJ_FROM_PTR(nlr.ret_val));
}

static int run_module(const char *name) {
    nlr_buf_t nlr;
    if (nlr_push(&nlr) == 0) {
        mp_obj_t args[4] = {mp_obj_new_str_from_cstr(name), mp_const_none, mp_const_none, mp_const_false};
        mp_builtin___import__(4, args);  // false: import as __main__
        nlr_pop();
        return 0;
    }
    return uncaught(MP_OBJ_FROM_PTR(nlr.ret_val));
}

static int repl(void) {
    for (;;) {
        int ret = pyexec_mode_kind == PYEXEC_MODE_RAW_REPL ? pyexec_raw_repl() : pyexec_friendly_repl();
        if (ret != 0) {
            return (ret & PYEXEC_FORCED_EXIT) ? (ret & 0xff) : 0;
        }
    }
}

static void add_path(const char *p, size_t n) {
    mp_obj_list_append(mp_sys_path, mp_obj_new_str_via_qstr(p, n));
}

static void init_sys_path(const char *argv0) {
    mp_sys_path = mp_obj_new_list(0, NULL);
    add_path("", 0);
    const char *env = getenv("MICROPYPATH");
    const char *p = env ? env : ".frozen";
    while (*p) {
        const char *end = strchr(p, ':');
        if (end == NULL) {
            end = p + strlen(p);
        }
        add_path(p, end - p);
        p = *end ? end + 1 : end;
    }
    // <folder of the executable>/lib: the port's Python modules (built next to the binary)
    char exe[4096];
    ssize_t n = readlink("/proc/self/exe", exe, sizeof(exe) - 5);
    if (n <= 0) {
        (void)argv0;
        return;
    }
    exe[n] = 0;
    char *slash = strrchr(exe, '/');
    strcpy(slash + 1, "lib");
    add_path(exe, strlen(exe));
}

static long parse_size(const char *s, bool *ok) {
    char *end;
    long v = strtol(s, &end, 0);
    if (*end == 'k' || *end == 'K') {
        v *= 1024;
        end++;
    } else if (*end == 'm' || *end == 'M') {
        v *= 1024 * 1024;
        end++;
    }
    *ok = *end == 0 && v > 0;
    return v;
}

int main(int argc, char **argv) {
    mp_cstack_init_with_sp_here(256 * 1024);
    long heap_size = DEFAULT_HEAP;
    int a = 1;
    // options that act before the VM exists
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "-X") == 0 && i + 1 < argc) {
            if (strncmp(argv[i + 1], "heapsize=", 9) == 0) {
                bool ok;
                heap_size = parse_size(argv[i + 1] + 9, &ok);
                if (!ok) {
                    return usage(argv[0]);
                }
            }
            i++;
        } else if (argv[i][0] != '-' || strcmp(argv[i], "-c") == 0 || strcmp(argv[i], "-m") == 0) {
            break;
        }
    }
    char *heap = malloc(heap_size);
    if (heap == NULL) {
        fprintf(stderr, "cannot allocate a heap of %ld bytes\n", heap_size);
        return 1;
    }
    gc_init(heap, heap + heap_size);
    mp_init();
    init_sys_path(argv[0]);
    mp_obj_list_init(MP_OBJ_TO_PTR(mp_sys_argv), 0);

    int ret = -1;
    for (a = 1; a < argc; a++) {
        if (strcmp(argv[a], "-X") == 0) {
            a++;
        } else if (strncmp(argv[a], "-O", 2) == 0) {
            MP_STATE_VM(mp_optimise_value) = argv[a][2] ? (argv[a][2] & 0xf) : 1;
        } else if (strcmp(argv[a], "-c") == 0 || strcmp(argv[a], "-m") == 0) {
            if (a + 1 >= argc) {
                return usage(argv[0]);
            }
            bool cmd = argv[a][1] == 'c';
            mp_obj_list_append(mp_sys_argv, MP_OBJ_NEW_QSTR(qstr_from_str(cmd ? "-c" : argv[a + 1])));
            for (int i = a + 2; i < argc; i++) {
                mp_obj_list_append(mp_sys_argv, MP_OBJ_NEW_QSTR(qstr_from_str(argv[i])));
            }
            ret = cmd ? execute(SRC_STR, argv[a + 1]) : run_module(argv[a + 1]);
            break;
        } else if (argv[a][0] == '-') {
            return usage(argv[0]);
        } else {
            char *real = realpath(argv[a], NULL);
            if (real == NULL) {
                fprintf(stderr, "%s: can't open file '%s': [Errno %d] %s\n", argv[0], argv[a], errno, strerror(errno));
                return 2;
            }
            char *dir = dirname(real);
            mp_obj_list_store(mp_sys_path, MP_OBJ_NEW_SMALL_INT(0), mp_obj_new_str_via_qstr(dir, strlen(dir)));
            free(real);
            for (int i = a; i < argc; i++) {
                mp_obj_list_append(mp_sys_argv, MP_OBJ_NEW_QSTR(qstr_from_str(argv[i])));
            }
            ret = execute(SRC_FILE, argv[a]);
            break;
        }
    }
    if (ret < 0) {
        ret = isatty(0) ? repl() : execute(SRC_FD, NULL);
    }
    mp_deinit();
    free(heap);
    return ret;
}

void gc_collect(void) {
    gc_collect_start();
    gc_helper_collect_regs_and_stack();
    gc_collect_end();
}

mp_import_stat_t mp_import_stat(const char *path) {
    struct stat st;
    if (stat(path, &st) == 0) {
        if (S_ISDIR(st.st_mode)) {
            return MP_IMPORT_STAT_DIR;
        } else if (S_ISREG(st.st_mode)) {
            return MP_IMPORT_STAT_FILE;
        }
    }
    return MP_IMPORT_STAT_NO_EXIST;
}

void nlr_jump_fail(void *val) {
    fprintf(stderr, "FATAL: uncaught NLR %p\n", val);
    exit(1);
}
