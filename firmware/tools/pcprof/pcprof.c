#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
typedef uint64_t qemu_plugin_id_t;
typedef struct qemu_info_t qemu_info_t;
struct qemu_plugin_tb;
enum qemu_plugin_op { QEMU_PLUGIN_INLINE_ADD_U64 };
typedef void (*tb_trans_cb_t)(qemu_plugin_id_t, struct qemu_plugin_tb *);
typedef void (*udata_cb_t)(qemu_plugin_id_t, void *);
typedef void (*vcpu_udata_cb_t)(unsigned int, void *);
extern void qemu_plugin_register_vcpu_tb_exec_cb(struct qemu_plugin_tb *, vcpu_udata_cb_t, int, void *);
extern void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t, tb_trans_cb_t);
extern size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *);
extern uint64_t qemu_plugin_tb_vaddr(const struct qemu_plugin_tb *);
extern void qemu_plugin_register_vcpu_tb_exec_inline(struct qemu_plugin_tb *, enum qemu_plugin_op, void *, uint64_t);
extern void qemu_plugin_register_atexit_cb(qemu_plugin_id_t, udata_cb_t, void *);
__attribute__((visibility("default"))) int qemu_plugin_version = 1;
typedef struct { uint64_t pc, n, count, count1; } ent;
static uint64_t split=~0ull, unsplit=~0ull; static int phase;
static void on_exec(unsigned int v, void *u){ ent *e=u; if(e->pc==split) phase=1; else if(e->pc==unsplit) phase=0; if(phase) e->count1++; else e->count++; }
static ent *ents; static size_t nents, cap; static char out[256] = "/tmp/prof/pcprof.txt";
static void tb_trans(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
    if (nents == cap) { cap = cap ? cap * 2 : 65536; ents = realloc(ents, cap * sizeof *ents); }
    /* pointer into realloc'd array would move: store index; use separate stable blocks instead */
    ent *e = malloc(sizeof *e); e->pc = qemu_plugin_tb_vaddr(tb); e->n = qemu_plugin_tb_n_insns(tb); e->count = 0;
    ((ent **)ents)[nents++] = e;
    e->count1=0; qemu_plugin_register_vcpu_tb_exec_cb(tb, on_exec, 0, e);
}
static void at_exit(qemu_plugin_id_t id, void *u) {
    FILE *f = fopen(out, "w");
    for (size_t i = 0; i < nents; i++) { ent *e = ((ent **)ents)[i]; if (e->count) fprintf(f, "%llx %llu %llu 0\n", (unsigned long long)e->pc, (unsigned long long)e->n, (unsigned long long)e->count); if (e->count1) fprintf(f, "%llx %llu %llu 1\n", (unsigned long long)e->pc, (unsigned long long)e->n, (unsigned long long)e->count1); }
    fclose(f);
}
__attribute__((visibility("default")))
int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info, int argc, char **argv) {
    for (int i = 0; i < argc; i++) { if (!strncmp(argv[i], "split=", 6)) split = strtoull(argv[i]+6,NULL,0)&~1ull;
        if (!strncmp(argv[i], "unsplit=", 8)) unsplit = strtoull(argv[i]+8,NULL,0)&~1ull;
        if (!strncmp(argv[i], "out=", 4)) snprintf(out, sizeof out, "%s", argv[i] + 4); }
    qemu_plugin_register_vcpu_tb_trans_cb(id, tb_trans);
    qemu_plugin_register_atexit_cb(id, at_exit, NULL);
    return 0;
}
