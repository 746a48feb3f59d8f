/* The MCAP Message records of the per-step topics (a part of wmr_stepper.c, compiled with
 * it). */

/* ---------------------------------------------------------------------------------------------
 * The MCAP Message records of a block of rows, all per-step topics: the bytes of
 * wmr.adapters.mcap.schemas.RowEncoder.encode (one record per row and topic, row after row,
 * topic after topic: opcode, length, channel id, sequence 0, log time = publish time = t_ns,
 * then the protobuf message: field 1 the Timestamp, then the topic's fixed body with the
 * row's doubles in its slots).  src is (n, n_src) float64: the signals and the derived
 * columns (the heading quaternion, computed by numpy as RowEncoder does).  Returns the bytes
 * written to out (room for n rows of the longest records) and the offset of each record.
 */
static void put_u64(unsigned char *p, unsigned long long v) {
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    memcpy(p, &v, 8); /* one store, where the byte loop below was eight */
#else
    for (int j = 0; j < 8; j++) p[j] = (unsigned char)(v >> (8 * j));
#endif
}

/* a protobuf varint field (tag, then 7 bits a byte), omitted when the value is 0 */
static int put_varint_field(unsigned char *p, unsigned char tag, unsigned long long v) {
    int len = 0;
    if (v == 0) return 0;
    p[len++] = tag;
    while (v >= 0x80) {
        p[len++] = (unsigned char)(v & 0x7F) | 0x80;
        v >>= 7;
    }
    p[len++] = (unsigned char)v;
    return len;
}

/* A Message record's head: opcode, record length, channel id, sequence, log and publish time */
static void put_message_head(unsigned char *r, int channel, unsigned int sequence,
                             unsigned long long t, size_t data_len) {
    r[0] = 0x05; /* Message */
    put_u64(r + 1, 2 + 4 + 8 + 8 + data_len);
    r[9] = (unsigned char)(channel & 0xFF);
    r[10] = (unsigned char)(channel >> 8);
    r[11] = (unsigned char)sequence;
    r[12] = (unsigned char)(sequence >> 8);
    r[13] = (unsigned char)(sequence >> 16);
    r[14] = (unsigned char)(sequence >> 24);
    put_u64(r + 15, t);
    put_u64(r + 23, t);
}

/* Row i's records, at out; each record's offset (from base) in offsets[k] */
static size_t encode_row(const wmr_layout *L, unsigned long long t, const double *row,
                         const double *extra, size_t extra_stride, unsigned char *out,
                         size_t base, long long *offsets) {
    unsigned char ts[12];
    int ts_len = put_varint_field(ts, 0x08, t / 1000000000ULL);
    ts_len += put_varint_field(ts + ts_len, 0x10, t % 1000000000ULL);
    const unsigned char *body = L->bodies;
    const int *off = L->slot_off, *from = L->slot_src;
    size_t pos = 0;
    for (int k = 0; k < L->n_topics; k++) {
        unsigned char *r = out + pos;
        size_t data_len = 2 + (size_t)ts_len + (size_t)L->body_len[k];
        offsets[k] = (long long)(base + pos);
        put_message_head(r, L->channel[k], 0, t, data_len);
        r[31] = 0x0A; /* Timestamp, length-delimited */
        r[32] = (unsigned char)ts_len;
        memcpy(r + 33, ts, (size_t)ts_len);
        unsigned char *b = r + 33 + ts_len;
        memcpy(b, body, (size_t)L->body_len[k]);
        for (int s = 0; s < L->n_slots[k]; s++) {
            const double *v = from[s] < L->n_sig
                                  ? row + from[s]
                                  : extra + (size_t)(from[s] - L->n_sig) * extra_stride;
            memcpy(b + off[s], v, 8);
        }
        pos += 31 + data_len;
        body += L->body_len[k];
        off += L->n_slots[k];
        from += L->n_slots[k];
    }
    return pos;
}

WMR_API long long wmr_encode_rows(int n, const long long *t_ns, const double *src, int n_src,
                                  int n_topics, const int *channel, const int *body_len,
                                  const unsigned char *bodies, const int *n_slots,
                                  const int *slot_off, const int *slot_src, unsigned char *out,
                                  long long *offsets) {
    wmr_layout L = {n_src, 0, n_topics, channel, body_len, bodies, n_slots, slot_off, slot_src};
    size_t pos = 0;
    for (int i = 0; i < n; i++)
        pos += encode_row(&L, (unsigned long long)t_ns[i], src + (size_t)i * (size_t)n_src,
                          NULL, 0, out + pos, pos, offsets + (size_t)i * (size_t)n_topics);
    return (long long)pos;
}

/* A chunk's rows: the records of wmr_encode_rows (the signals in block, n x n_sig, row after
 * row; the extra columns in extra, n_extra x n, column after column: what numpy's sin and cos
 * write in place), and the chunk's Message Index records at index, one per
 * topic in topic order, as mcap packs them: opcode 0x07, record length, channel id, length of
 * the entries, then (log time, record offset) per row.  Returns the records' bytes. */
WMR_API long long wmr_encode_chunk(const wmr_layout *L, int n, const long long *t_ns,
                                   const double *block, const double *extra,
                                   unsigned char *out, unsigned char *index) {
    size_t pos = 0, entries = 16 * (size_t)n, rec = 15 + entries;
    long long offsets[WMR_MAX_TOPICS];
    if (L->n_topics > WMR_MAX_TOPICS) return -1;
    for (int k = 0; k < L->n_topics; k++) {
        unsigned char *m = index + (size_t)k * rec;
        m[0] = 0x07; /* Message Index */
        put_u64(m + 1, 6 + entries);
        m[9] = (unsigned char)(L->channel[k] & 0xFF);
        m[10] = (unsigned char)(L->channel[k] >> 8);
        m[11] = (unsigned char)entries;
        m[12] = (unsigned char)(entries >> 8);
        m[13] = (unsigned char)(entries >> 16);
        m[14] = (unsigned char)(entries >> 24);
    }
    for (int i = 0; i < n; i++) {
        unsigned long long t = (unsigned long long)t_ns[i];
        pos += encode_row(L, t, block + (size_t)i * (size_t)L->n_sig, extra + i, (size_t)n,
                          out + pos, pos, offsets);
        for (int k = 0; k < L->n_topics; k++) {
            unsigned char *e = index + (size_t)k * rec + 15 + 16 * (size_t)i;
            put_u64(e, t);
            put_u64(e + 8, (unsigned long long)offsets[k]);
        }
    }
    return (long long)pos;
}
