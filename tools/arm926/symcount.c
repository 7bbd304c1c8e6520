/*
 * symcount: a QEMU TCG plugin that counts the guest instructions executed,
 * per symbol of the guest binary, and writes them to a file at exit.
 *
 * Written here because Debian's qemu-user accepts -plugin but ships no
 * plugins, and QEMU's own examples count blocks (tests/plugin/bb.c) or
 * hot blocks (contrib/plugins/hotblocks.c) but not functions. It is
 * built against the qemu-plugin.h of the installed QEMU's source
 * (`apt-get source qemu`) by tools/arm926/board.
 *
 * At translation, each block is cut into runs of instructions of one
 * symbol; the first instruction of a run gets an inline add of the run's
 * length to that symbol's counter (no call per instruction). Instructions
 * outside the binary's symbol table (shared libraries, the vDSO) count as
 * "[no symbol]".
 *
 * Usage: qemu-arm -plugin ./libsymcount.so,out=FILE[,split=TEXT] ... ;
 * FILE gets "count<TAB>symbol" lines, the total first as "total". With
 * split=TEXT, the runs of symbols whose name contains TEXT are counted
 * apart, as "symbol@0xADDRESS" (the run's first instruction; addr2line
 * gives its source line).
 */
#include <glib.h>
#include <inttypes.h>
#include <stdio.h>
#include <string.h>

#include <qemu-plugin.h>

QEMU_PLUGIN_EXPORT int qemu_plugin_version = QEMU_PLUGIN_VERSION;

typedef struct {
    const char *name;
    uint64_t count;
} Counter;

static GHashTable *counters;
static GMutex lock;
static char *out_path;
static char *split;

static Counter *counter_for(const char *name)
{
    Counter *c;
    g_mutex_lock(&lock);
    c = g_hash_table_lookup(counters, name);
    if (!c) {
        c = g_new0(Counter, 1);
        c->name = g_strdup(name);
        g_hash_table_insert(counters, (gpointer)c->name, c);
    }
    g_mutex_unlock(&lock);
    return c;
}

static void tb_trans(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    size_t n = qemu_plugin_tb_n_insns(tb);
    size_t start = 0;
    while (start < n) {
        struct qemu_plugin_insn *first = qemu_plugin_tb_get_insn(tb, start);
        const char *sym = qemu_plugin_insn_symbol(first);
        size_t end = start + 1;
        while (end < n) {
            const char *s = qemu_plugin_insn_symbol(qemu_plugin_tb_get_insn(tb, end));
            if (s != sym && (!s || !sym || strcmp(s, sym) != 0)) {
                break;
            }
            end++;
        }
        Counter *c;
        if (sym && split && strstr(sym, split)) {
            char *key = g_strdup_printf("%s@0x%" PRIx64, sym, qemu_plugin_insn_vaddr(first));
            c = counter_for(key);
            g_free(key);
        } else {
            c = counter_for(sym ? sym : "[no symbol]");
        }
        qemu_plugin_register_vcpu_insn_exec_inline(first, QEMU_PLUGIN_INLINE_ADD_U64,
                                                   &c->count, end - start);
        start = end;
    }
}

static gint by_count(gconstpointer a, gconstpointer b)
{
    const Counter *x = a, *y = b;
    return x->count < y->count ? 1 : x->count > y->count ? -1 : 0;
}

static void at_exit(qemu_plugin_id_t id, void *p)
{
    GList *all = g_list_sort(g_hash_table_get_values(counters), by_count);
    uint64_t total = 0;
    for (GList *it = all; it; it = it->next) {
        total += ((Counter *)it->data)->count;
    }
    FILE *f = fopen(out_path, "w");
    if (!f) {
        qemu_plugin_outs("symcount: cannot write the output file\n");
        return;
    }
    fprintf(f, "%" PRIu64 "\ttotal\n", total);
    for (GList *it = all; it; it = it->next) {
        Counter *c = it->data;
        if (c->count) {
            fprintf(f, "%" PRIu64 "\t%s\n", c->count, c->name);
        }
    }
    fclose(f);
    g_list_free(all);
}

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info,
                                           int argc, char **argv)
{
    for (int i = 0; i < argc; i++) {
        if (g_str_has_prefix(argv[i], "out=")) {
            out_path = g_strdup(argv[i] + 4);
        } else if (g_str_has_prefix(argv[i], "split=")) {
            split = g_strdup(argv[i] + 6);
        } else {
            fprintf(stderr, "symcount: unknown option %s (use out=FILE, split=TEXT)\n", argv[i]);
            return -1;
        }
    }
    if (!out_path) {
        fprintf(stderr, "symcount: give out=FILE\n");
        return -1;
    }
    counters = g_hash_table_new(g_str_hash, g_str_equal);
    qemu_plugin_register_vcpu_tb_trans_cb(id, tb_trans);
    qemu_plugin_register_atexit_cb(id, at_exit, NULL);
    return 0;
}
