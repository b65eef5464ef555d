// _json.dumps: JSON text from the core's own JSON printers (the PRINT_JSON kind of dict, list,
// str, int, bool, None), without building it piece by piece in Python: lib/json.py uses it when
// the port has it (the rig's DUT reports its statistics in JSON on a small heap).
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

static const mp_rom_map_elem_t json_globals_table[] = {
    { MP_ROM_QSTR(MP_QSTR___name__), MP_ROM_QSTR(MP_QSTR__json) },
    { MP_ROM_QSTR(MP_QSTR_dumps), MP_ROM_PTR(&json_dumps_obj) },
};
static MP_DEFINE_CONST_DICT(json_globals, json_globals_table);

const mp_obj_module_t mp_module__json = {
    .base = { &mp_type_module },
    .globals = (mp_obj_dict_t *)&json_globals,
};
MP_REGISTER_MODULE(MP_QSTR__json, mp_module__json);
