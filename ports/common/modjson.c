// _json: dumps from the core's own JSON printers (the PRINT_JSON kind of dict, list, str, int,
// bool, None) and loads, a small recursive parser, so that neither builds text or values piece
// by piece in Python: lib/json.py uses them when the port has them (the rig's DUT exchanges JSON
// lines with the test on every control-channel gate, on a small heap).
#include <math.h>
#include <string.h>

#include "py/objstr.h"
#include "py/parsenum.h"
#include "py/runtime.h"

static mp_obj_t json_dumps(mp_obj_t obj) {
    vstr_t vstr;
    mp_print_ext_t print;
    vstr_init_print(&vstr, 16, &print.base);
    print.item_separator = ", ";  // CPython's defaults
    print.key_separator = ": ";
    mp_obj_print_helper(&print.base, obj, PRINT_JSON);
    return mp_obj_new_str_from_utf8_vstr(&vstr);
}
static MP_DEFINE_CONST_FUN_OBJ_1(json_dumps_obj, json_dumps);

typedef struct _parser_t {
    const char *p;
    const char *end;
} parser_t;

static MP_NORETURN void fail(parser_t *ps) {
    (void)ps;
    mp_raise_ValueError(MP_ERROR_TEXT("syntax error in JSON"));
}

static void skip_ws(parser_t *ps) {
    while (ps->p < ps->end && (*ps->p == ' ' || *ps->p == '\t' || *ps->p == '\n' || *ps->p == '\r')) {
        ps->p++;
    }
}

static bool take(parser_t *ps, const char *word) {
    size_t n = strlen(word);
    if ((size_t)(ps->end - ps->p) >= n && memcmp(ps->p, word, n) == 0) {
        ps->p += n;
        return true;
    }
    return false;
}

static int hex4(parser_t *ps) {
    if (ps->end - ps->p < 4) {
        fail(ps);
    }
    int v = 0;
    for (int i = 0; i < 4; i++) {
        char c = *ps->p++;
        v <<= 4;
        if (c >= '0' && c <= '9') {
            v |= c - '0';
        } else if ((c | 0x20) >= 'a' && (c | 0x20) <= 'f') {
            v |= (c | 0x20) - 'a' + 10;
        } else {
            fail(ps);
        }
    }
    return v;
}

static mp_obj_t parse_string(parser_t *ps) {
    ps->p++;  // the opening quote
    vstr_t vstr;
    vstr_init(&vstr, 16);
    for (;;) {
        if (ps->p >= ps->end) {
            fail(ps);
        }
        char c = *ps->p++;
        if (c == '"') {
            break;
        }
        if (c != '\\') {
            vstr_add_byte(&vstr, c);
            continue;
        }
        if (ps->p >= ps->end) {
            fail(ps);
        }
        c = *ps->p++;
        switch (c) {
            case 'b':
                c = '\b';
                break;
            case 'f':
                c = '\f';
                break;
            case 'n':
                c = '\n';
                break;
            case 'r':
                c = '\r';
                break;
            case 't':
                c = '\t';
                break;
            case 'u': {
                unichar u = hex4(ps);
                if (u >= 0xD800 && u < 0xDC00 && take(ps, "\\u")) {  // a surrogate pair
                    u = 0x10000 + ((u - 0xD800) << 10) + (hex4(ps) - 0xDC00);
                }
                vstr_add_char(&vstr, u);
                continue;
            }
            case '"':
            case '\\':
            case '/':
                break;
            default:
                fail(ps);
        }
        vstr_add_byte(&vstr, c);
    }
    return mp_obj_new_str_from_vstr(&vstr);
}

static mp_obj_t parse_value(parser_t *ps) {
    skip_ws(ps);
    if (ps->p >= ps->end) {
        fail(ps);
    }
    char c = *ps->p;
    if (c == '"') {
        return parse_string(ps);
    }
    if (c == '{' || c == '[') {
        bool dict = c == '{';
        char close = dict ? '}' : ']';
        mp_obj_t o = dict ? mp_obj_new_dict(0) : mp_obj_new_list(0, NULL);
        ps->p++;
        skip_ws(ps);
        if (ps->p < ps->end && *ps->p == close) {
            ps->p++;
            return o;
        }
        for (;;) {
            if (dict) {
                skip_ws(ps);
                if (ps->p >= ps->end || *ps->p != '"') {
                    fail(ps);
                }
                mp_obj_t key = parse_string(ps);
                skip_ws(ps);
                if (!take(ps, ":")) {
                    fail(ps);
                }
                mp_obj_dict_store(o, key, parse_value(ps));
            } else {
                mp_obj_list_append(o, parse_value(ps));
            }
            skip_ws(ps);
            if (ps->p >= ps->end) {
                fail(ps);
            }
            c = *ps->p++;
            if (c == close) {
                return o;
            }
            if (c != ',') {
                fail(ps);
            }
        }
    }
    if (take(ps, "true")) {
        return mp_const_true;
    }
    if (take(ps, "false")) {
        return mp_const_false;
    }
    if (take(ps, "null")) {
        return mp_const_none;
    }
    #if MICROPY_PY_BUILTINS_FLOAT
    if (take(ps, "NaN")) {
        return mp_obj_new_float(MICROPY_FLOAT_C_FUN(nan)(""));
    }
    if (take(ps, "Infinity")) {
        return mp_obj_new_float(INFINITY);
    }
    if (take(ps, "-Infinity")) {
        return mp_obj_new_float(-INFINITY);
    }
    #endif
    const char *start = ps->p;
    bool is_float = false;
    while (ps->p < ps->end && strchr("+-0123456789.eE", *ps->p) != NULL && *ps->p) {
        is_float |= *ps->p == '.' || *ps->p == 'e' || *ps->p == 'E';
        ps->p++;
    }
    if (ps->p == start) {
        fail(ps);
    }
    if (is_float) {
        return mp_parse_num_float(start, ps->p - start, false, NULL);
    }
    return mp_parse_num_integer(start, ps->p - start, 10, NULL);
}

static mp_obj_t json_loads(mp_obj_t text) {
    size_t len;
    const char *s = mp_obj_str_get_data(text, &len);
    parser_t ps = {s, s + len};
    mp_obj_t v = parse_value(&ps);
    skip_ws(&ps);
    if (ps.p != ps.end) {
        fail(&ps);
    }
    return v;
}
static MP_DEFINE_CONST_FUN_OBJ_1(json_loads_obj, json_loads);

static const mp_rom_map_elem_t json_globals_table[] = {
    { MP_ROM_QSTR(MP_QSTR___name__), MP_ROM_QSTR(MP_QSTR__json) },
    { MP_ROM_QSTR(MP_QSTR_dumps), MP_ROM_PTR(&json_dumps_obj) },
    { MP_ROM_QSTR(MP_QSTR_loads), MP_ROM_PTR(&json_loads_obj) },
};
static MP_DEFINE_CONST_DICT(json_globals, json_globals_table);

const mp_obj_module_t mp_module__json = {
    .base = { &mp_type_module },
    .globals = (mp_obj_dict_t *)&json_globals,
};
MP_REGISTER_MODULE(MP_QSTR__json, mp_module__json);
