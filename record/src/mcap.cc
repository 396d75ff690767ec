#include "skinbus/record/mcap.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>
#include <tuple>
#include <utility>

namespace skinbus::record {

namespace {

constexpr std::array<uint8_t, 8> kMagic = {0x89, 'M', 'C', 'A', 'P', '0', '\r', '\n'};
constexpr std::size_t kRecordHeaderBytes = 9;  // opcode, uint64 length

enum Op : uint8_t {
  kHeader = 0x01,
  kFooter = 0x02,
  kSchema = 0x03,
  kChannel = 0x04,
  kMessage = 0x05,
  kChunk = 0x06,
  kMessageIndex = 0x07,
  kChunkIndex = 0x08,
  kAttachment = 0x09,
  kAttachmentIndex = 0x0A,
  kStatistics = 0x0B,
  kMetadata = 0x0C,
  kMetadataIndex = 0x0D,
  kSummaryOffset = 0x0E,
  kDataEnd = 0x0F,
};

// CRC-32 tables for slicing by 8 (eight bytes a step): table[0] is the classic byte table,
// table[k][i] the CRC of byte i followed by k zero bytes.
std::array<std::array<uint32_t, 256>, 8> make_crc_tables() {
  std::array<std::array<uint32_t, 256>, 8> t{};
  for (uint32_t i = 0; i < 256; ++i) {
    uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
    t[0][i] = c;
  }
  for (uint32_t i = 0; i < 256; ++i) {
    for (std::size_t k = 1; k < 8; ++k) t[k][i] = (t[k - 1][i] >> 8) ^ t[0][t[k - 1][i] & 0xFFu];
  }
  return t;
}

// Little-endian record content.
class Bytes {
 public:
  std::vector<uint8_t> b;
  template <typename T>
  void num(T v) {
    const auto* p = reinterpret_cast<const uint8_t*>(&v);
    b.insert(b.end(), p, p + sizeof(T));
  }
  void str(const std::string& s) {
    num(static_cast<uint32_t>(s.size()));
    b.insert(b.end(), s.begin(), s.end());
  }
  void map(const std::map<std::string, std::string>& m) {
    Bytes inner;
    for (const auto& [k, v] : m) {
      inner.str(k);
      inner.str(v);
    }
    num(static_cast<uint32_t>(inner.b.size()));
    b.insert(b.end(), inner.b.begin(), inner.b.end());
  }
  void raw(std::span<const uint8_t> d) { b.insert(b.end(), d.begin(), d.end()); }
};

// One record: opcode, length, content.
std::vector<uint8_t> record(uint8_t op, const std::vector<uint8_t>& content) {
  Bytes r;
  r.num(op);
  r.num(static_cast<uint64_t>(content.size()));
  r.raw(content);
  return std::move(r.b);
}

}  // namespace

uint32_t crc32(std::span<const uint8_t> data, uint32_t crc) {
  static const std::array<std::array<uint32_t, 256>, 8> t = make_crc_tables();
  crc = ~crc;
  const uint8_t* p = data.data();
  std::size_t n = data.size();
  for (; n >= 8; n -= 8, p += 8) {
    uint32_t lo = 0, hi = 0;
    std::memcpy(&lo, p, 4);
    std::memcpy(&hi, p + 4, 4);
    lo ^= crc;
    crc = t[7][lo & 0xFFu] ^ t[6][(lo >> 8) & 0xFFu] ^ t[5][(lo >> 16) & 0xFFu] ^ t[4][lo >> 24] ^
          t[3][hi & 0xFFu] ^ t[2][(hi >> 8) & 0xFFu] ^ t[1][(hi >> 16) & 0xFFu] ^ t[0][hi >> 24];
  }
  for (; n > 0; --n, ++p) crc = t[0][(crc ^ *p) & 0xFFu] ^ (crc >> 8);
  return ~crc;
}

// ---- writer ----------------------------------------------------------------------------------

struct McapWriter::Impl {
  std::FILE* f = nullptr;
  std::string path;
  McapWriterOptions options;
  Status error;
  uint64_t offset = 0;  // bytes written
  uint64_t message_count = 0;
  uint32_t data_crc = 0;
  bool in_data = true;  // the data section's bytes are summed into data_crc

  // Writes `bytes` at the offset (and into the data section's CRC while in it); the first failure
  // is kept in `error`.
  void put(std::span<const uint8_t> bytes) {
    if (error.ok() && std::fwrite(bytes.data(), 1, bytes.size(), f) != bytes.size()) {
      error = make_error(ErrorCode::kIo, path + ": write failed: " + std::strerror(errno));
    }
    if (in_data) data_crc = crc32(bytes, data_crc);
    offset += bytes.size();
  }

  std::vector<std::vector<uint8_t>> schema_records, channel_records;
  std::map<uint16_t, uint32_t> sequence;  // per channel: the next sequence number
  std::map<uint16_t, uint64_t> channel_counts;
  uint64_t message_start_ns = 0, message_end_ns = 0;
  uint32_t attachment_count = 0, metadata_count = 0;

  // The open chunk.
  std::vector<uint8_t> chunk;
  uint64_t chunk_start_ns = 0, chunk_end_ns = 0;
  std::map<uint16_t, std::vector<std::pair<uint64_t, uint64_t>>> chunk_index;  // time, offset
  std::vector<std::vector<uint8_t>> chunk_indexes, attachment_indexes, metadata_indexes;
};

McapWriter::McapWriter(std::FILE* f, std::string path, McapWriterOptions options)
    : impl_(std::make_unique<Impl>()) {
  impl_->f = f;
  impl_->path = std::move(path);
  impl_->options = std::move(options);
}

McapWriter::~McapWriter() {
  if (impl_->f != nullptr) std::fclose(impl_->f);
}

Result<std::unique_ptr<McapWriter>> McapWriter::create(const std::string& path,
                                                       McapWriterOptions options) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) {
    return make_error(ErrorCode::kIo, path + ": cannot create: " + std::strerror(errno));
  }
  std::unique_ptr<McapWriter> w(new McapWriter(f, path, std::move(options)));
  Impl& s = *w->impl_;
  s.put(kMagic);
  Bytes h;
  h.str(s.options.profile);
  h.str(s.options.library);
  s.put(record(kHeader, h.b));
  if (!s.error.ok()) return s.error.error();
  return w;
}

uint16_t McapWriter::add_schema(const std::string& name, const std::string& encoding,
                                std::span<const uint8_t> data) {
  Impl& s = *impl_;
  const auto id = static_cast<uint16_t>(s.schema_records.size() + 1);
  Bytes c;
  c.num(id);
  c.str(name);
  c.str(encoding);
  c.num(static_cast<uint32_t>(data.size()));
  c.raw(data);
  s.schema_records.push_back(record(kSchema, c.b));
  s.put(s.schema_records.back());
  return id;
}

uint16_t McapWriter::add_channel(uint16_t schema_id, const std::string& topic,
                                 const std::string& message_encoding,
                                 const std::map<std::string, std::string>& metadata) {
  Impl& s = *impl_;
  const auto id = static_cast<uint16_t>(s.channel_records.size() + 1);
  Bytes c;
  c.num(id);
  c.num(schema_id);
  c.str(topic);
  c.str(message_encoding);
  c.map(metadata);
  s.channel_records.push_back(record(kChannel, c.b));
  s.sequence[id] = 0;
  s.channel_counts[id] = 0;
  s.put(s.channel_records.back());
  return id;
}

namespace {

// Closes the open chunk: the Chunk record, its Message Indexes, its Chunk Index (kept).
void flush_chunk(McapWriter::Impl& s) {
  if (s.chunk.empty()) return;
  const uint64_t chunk_start = s.offset;
  Bytes c;
  c.num(s.chunk_start_ns);
  c.num(s.chunk_end_ns);
  c.num(static_cast<uint64_t>(s.chunk.size()));
  c.num(crc32(s.chunk));
  c.str("");  // uncompressed
  c.num(static_cast<uint64_t>(s.chunk.size()));
  c.raw(s.chunk);
  const std::vector<uint8_t> chunk_record = record(kChunk, c.b);
  s.put(chunk_record);
  const uint64_t index_start = s.offset;
  Bytes offsets;  // map<uint16, uint64>: channel -> its Message Index's offset
  for (const auto& [channel, entries] : s.chunk_index) {
    offsets.num(channel);
    offsets.num(s.offset);
    Bytes m;
    m.num(channel);
    m.num(static_cast<uint32_t>(entries.size() * 16));
    for (const auto& [t, o] : entries) {
      m.num(t);
      m.num(o);
    }
    s.put(record(kMessageIndex, m.b));
  }
  Bytes ci;
  ci.num(s.chunk_start_ns);
  ci.num(s.chunk_end_ns);
  ci.num(chunk_start);
  ci.num(static_cast<uint64_t>(chunk_record.size()));
  ci.num(static_cast<uint32_t>(offsets.b.size()));
  ci.raw(offsets.b);
  ci.num(s.offset - index_start);
  ci.str("");
  ci.num(static_cast<uint64_t>(s.chunk.size()));  // compressed size: stored as is
  ci.num(static_cast<uint64_t>(s.chunk.size()));
  s.chunk_indexes.push_back(record(kChunkIndex, ci.b));
  s.chunk.clear();
  s.chunk_index.clear();
}

}  // namespace

Status McapWriter::write_message(uint16_t channel_id, uint64_t log_time_ns,
                                 uint64_t publish_time_ns, std::span<const uint8_t> data) {
  Impl& s = *impl_;
  auto seq = s.sequence.find(channel_id);
  if (seq == s.sequence.end()) {
    return make_error(
        ErrorCode::kInvalidArgument,
        s.path + ": message on channel " + std::to_string(channel_id) + ", which was not added");
  }
  if (s.chunk.empty()) {
    s.chunk_start_ns = log_time_ns;
    s.chunk_end_ns = log_time_ns;
  }
  s.chunk_start_ns = std::min(s.chunk_start_ns, log_time_ns);
  s.chunk_end_ns = std::max(s.chunk_end_ns, log_time_ns);
  if (s.message_count == 0) {
    s.message_start_ns = log_time_ns;
    s.message_end_ns = log_time_ns;
  }
  s.message_start_ns = std::min(s.message_start_ns, log_time_ns);
  s.message_end_ns = std::max(s.message_end_ns, log_time_ns);
  s.chunk_index[channel_id].emplace_back(log_time_ns, s.chunk.size());
  // The Message record straight into the open chunk (no copy of its own).
  const uint64_t length = 2 + 4 + 8 + 8 + data.size();
  const std::size_t at = s.chunk.size();
  s.chunk.resize(at + kRecordHeaderBytes + static_cast<std::size_t>(length));
  uint8_t* p = s.chunk.data() + at;
  auto put = [&p](const auto& v) {
    std::memcpy(p, &v, sizeof v);
    p += sizeof v;
  };
  put(static_cast<uint8_t>(kMessage));
  put(length);
  put(channel_id);
  put(seq->second++);
  put(log_time_ns);
  put(publish_time_ns);
  if (!data.empty()) std::memcpy(p, data.data(), data.size());
  ++s.channel_counts[channel_id];
  ++s.message_count;
  if (s.chunk.size() >= s.options.chunk_bytes) flush_chunk(s);
  return s.error;
}

Status McapWriter::write_attachment(const std::string& name, const std::string& media_type,
                                    std::span<const uint8_t> data, uint64_t log_time_ns,
                                    uint64_t create_time_ns) {
  Impl& s = *impl_;
  flush_chunk(s);  // attachments sit between chunks
  Bytes a;
  a.num(log_time_ns);
  a.num(create_time_ns);
  a.str(name);
  a.str(media_type);
  a.num(static_cast<uint64_t>(data.size()));
  a.raw(data);
  a.num(crc32(a.b));
  const uint64_t at = s.offset;
  const std::vector<uint8_t> r = record(kAttachment, a.b);
  s.put(r);
  Bytes i;
  i.num(at);
  i.num(static_cast<uint64_t>(r.size()));
  i.num(log_time_ns);
  i.num(create_time_ns);
  i.num(static_cast<uint64_t>(data.size()));
  i.str(name);
  i.str(media_type);
  s.attachment_indexes.push_back(record(kAttachmentIndex, i.b));
  ++s.attachment_count;
  return s.error;
}

Status McapWriter::write_metadata(const std::string& name,
                                  const std::map<std::string, std::string>& map) {
  Impl& s = *impl_;
  flush_chunk(s);
  Bytes m;
  m.str(name);
  m.map(map);
  const uint64_t at = s.offset;
  const std::vector<uint8_t> r = record(kMetadata, m.b);
  s.put(r);
  Bytes i;
  i.num(at);
  i.num(static_cast<uint64_t>(r.size()));
  i.str(name);
  s.metadata_indexes.push_back(record(kMetadataIndex, i.b));
  ++s.metadata_count;
  return s.error;
}

Status McapWriter::close() {
  Impl& s = *impl_;
  if (s.f == nullptr) return s.error;
  flush_chunk(s);
  Bytes end;
  end.num(s.data_crc);
  s.in_data = false;
  s.put(record(kDataEnd, end.b));

  // The summary: each group's records, then a Summary Offset per group; its CRC runs from the
  // summary's first byte through the footer's offsets.
  const uint64_t summary_start = s.offset;
  uint32_t summary_crc = 0;
  std::vector<std::tuple<uint8_t, uint64_t, uint64_t>> groups;
  auto group = [&](uint8_t op, const std::vector<std::vector<uint8_t>>& records) {
    if (records.empty()) return;
    const uint64_t start = s.offset;
    for (const auto& r : records) {
      s.put(r);
      summary_crc = crc32(r, summary_crc);
    }
    groups.emplace_back(op, start, s.offset - start);
  };
  Bytes st;
  st.num(s.message_count);
  st.num(static_cast<uint16_t>(s.schema_records.size()));
  st.num(static_cast<uint32_t>(s.channel_records.size()));
  st.num(s.attachment_count);
  st.num(s.metadata_count);
  st.num(static_cast<uint32_t>(s.chunk_indexes.size()));
  st.num(s.message_start_ns);
  st.num(s.message_end_ns);
  Bytes counts;
  for (const auto& [channel, n] : s.channel_counts) {
    counts.num(channel);
    counts.num(n);
  }
  st.num(static_cast<uint32_t>(counts.b.size()));
  st.raw(counts.b);
  group(kSchema, s.schema_records);
  group(kChannel, s.channel_records);
  group(kStatistics, {record(kStatistics, st.b)});
  group(kChunkIndex, s.chunk_indexes);
  group(kAttachmentIndex, s.attachment_indexes);
  group(kMetadataIndex, s.metadata_indexes);
  const uint64_t offsets_start = s.offset;
  for (const auto& [op, start, length] : groups) {
    Bytes o;
    o.num(op);
    o.num(start);
    o.num(length);
    const std::vector<uint8_t> r = record(kSummaryOffset, o.b);
    s.put(r);
    summary_crc = crc32(r, summary_crc);
  }
  Bytes footer;
  footer.num(static_cast<uint8_t>(kFooter));
  footer.num(static_cast<uint64_t>(8 + 8 + 4));
  footer.num(summary_start);
  footer.num(offsets_start);
  summary_crc = crc32(footer.b, summary_crc);
  footer.num(summary_crc);
  s.put(footer.b);
  s.put(kMagic);
  if (std::fclose(s.f) != 0 && s.error.ok()) {
    s.error = make_error(ErrorCode::kIo, s.path + ": close failed: " + std::strerror(errno));
  }
  s.f = nullptr;
  return s.error;
}

uint64_t McapWriter::bytes_written() const {
  return impl_->offset;
}
uint64_t McapWriter::message_count() const {
  return impl_->message_count;
}

// ---- reader ----------------------------------------------------------------------------------

struct McapReader::Impl {
  std::FILE* f = nullptr;
  bool owned = false;
  std::string name;
  McapReaderOptions options;
  uint64_t offset = 0;  // of the next record in the file
  std::string profile;
  std::map<uint16_t, McapSchema> schemas;
  std::map<uint16_t, McapChannel> channels;
  std::vector<McapAttachment> attachments;
  std::vector<std::pair<std::string, std::map<std::string, std::string>>> metadata;
  // The open chunk's records and the read position in them.
  std::vector<uint8_t> chunk;
  std::size_t chunk_pos = 0;
  uint64_t chunk_offset = 0;  // the chunk record's offset, for errors
  bool done = false;

  Error parse_error(uint64_t at, const std::string& what) const {
    return make_error(ErrorCode::kParse, name + ": byte " + std::to_string(at) + ": " + what);
  }
};

namespace {

// Reads little-endian fields from a record's content; `ok` false after a short read.
class Cursor {
 public:
  Cursor(const uint8_t* p, std::size_t n) : p_(p), n_(n) {}
  template <typename T>
  T num() {
    T v{};
    if (n_ - pos_ < sizeof(T)) {
      ok = false;
      pos_ = n_;
      return v;
    }
    std::memcpy(&v, p_ + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::string str() {
    const auto len = num<uint32_t>();
    if (!fits(len)) return {};
    std::string s(reinterpret_cast<const char*>(p_ + pos_), len);
    pos_ += len;
    return s;
  }
  std::vector<uint8_t> bytes(uint64_t len) {
    if (!fits(len)) return {};
    std::vector<uint8_t> b(p_ + pos_, p_ + pos_ + len);
    pos_ += static_cast<std::size_t>(len);
    return b;
  }
  std::map<std::string, std::string> map() {
    const auto len = num<uint32_t>();
    std::map<std::string, std::string> m;
    if (!fits(len)) return m;
    Cursor inner(p_ + pos_, len);
    while (inner.ok && inner.remaining() > 0) {
      std::string k = inner.str();
      std::string v = inner.str();
      if (inner.ok) m[std::move(k)] = std::move(v);
    }
    ok = inner.ok;
    pos_ += len;
    return m;
  }
  std::size_t remaining() const { return n_ - pos_; }
  std::size_t pos() const { return pos_; }
  bool ok = true;

 private:
  // Whether `len` more bytes are there; if not, the cursor fails and stays at the end.
  bool fits(uint64_t len) {
    if (ok && len <= n_ - pos_) return true;
    ok = false;
    pos_ = n_;
    return false;
  }

  const uint8_t* p_;
  std::size_t n_;
  std::size_t pos_ = 0;
};

}  // namespace

McapReader::McapReader() : impl_(std::make_unique<Impl>()) {}

McapReader::~McapReader() {
  if (impl_->owned && impl_->f != nullptr) std::fclose(impl_->f);
}

Result<std::unique_ptr<McapReader>> McapReader::open(const std::string& path,
                                                     McapReaderOptions options) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (f == nullptr) {
    return make_error(errno == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIo,
                      path + ": cannot open: " + std::strerror(errno));
  }
  auto r = open(f, path, options);
  if (!r.ok()) {
    std::fclose(f);
    return r.error();
  }
  (*r)->impl_->owned = true;
  return r;
}

namespace {

// Reads one record's header and content at the file's position: false at a clean end of file.
Result<bool> read_record(McapReader::Impl& s, uint8_t* op, std::vector<uint8_t>* content) {
  uint8_t head[kRecordHeaderBytes];
  const std::size_t got = std::fread(head, 1, sizeof head, s.f);
  if (got == 0) return false;
  if (got != sizeof head) return s.parse_error(s.offset, "the file ends inside a record header");
  *op = head[0];
  uint64_t len = 0;
  std::memcpy(&len, head + 1, 8);
  if (len > s.options.max_record_bytes) {
    return s.parse_error(s.offset, "a record of " + std::to_string(len) +
                                       " bytes (over the reader's limit of " +
                                       std::to_string(s.options.max_record_bytes) + ")");
  }
  content->resize(static_cast<std::size_t>(len));
  if (len > 0 && std::fread(content->data(), 1, content->size(), s.f) != content->size()) {
    return s.parse_error(s.offset, "the file ends inside a record (opcode " + std::to_string(*op) +
                                       ", " + std::to_string(len) + " bytes)");
  }
  return true;
}

}  // namespace

Result<std::unique_ptr<McapReader>> McapReader::open(std::FILE* f, const std::string& name,
                                                     McapReaderOptions options) {
  std::unique_ptr<McapReader> r(new McapReader());
  Impl& s = *r->impl_;
  s.f = f;
  s.name = name;
  s.options = options;
  std::array<uint8_t, 8> magic{};
  if (std::fread(magic.data(), 1, magic.size(), f) != magic.size() || magic != kMagic) {
    return make_error(ErrorCode::kParse, name + ": not an MCAP file (no MCAP magic)");
  }
  s.offset = magic.size();
  uint8_t op = 0;
  std::vector<uint8_t> content;
  auto got = read_record(s, &op, &content);
  if (!got.ok()) return got.error();
  if (!*got || op != kHeader) return s.parse_error(s.offset, "the Header record is missing");
  Cursor c(content.data(), content.size());
  s.profile = c.str();
  (void)c.str();  // library
  if (!c.ok) return s.parse_error(s.offset, "a malformed Header record");
  s.offset += kRecordHeaderBytes + content.size();
  return r;
}

namespace {

// Handles one record outside or inside a chunk: a message into `out` (true), else false.
Result<bool> handle(McapReader::Impl& s, uint8_t op, const uint8_t* p, std::size_t n, uint64_t at,
                    McapMessage* out) {
  Cursor c(p, n);
  switch (op) {
    case kSchema: {
      McapSchema sc;
      sc.id = c.num<uint16_t>();
      sc.name = c.str();
      sc.encoding = c.str();
      sc.data = c.bytes(c.num<uint32_t>());
      if (!c.ok) return s.parse_error(at, "a malformed Schema record");
      s.schemas[sc.id] = std::move(sc);
      return false;
    }
    case kChannel: {
      McapChannel ch;
      ch.id = c.num<uint16_t>();
      ch.schema_id = c.num<uint16_t>();
      ch.topic = c.str();
      ch.message_encoding = c.str();
      ch.metadata = c.map();
      if (!c.ok) return s.parse_error(at, "a malformed Channel record");
      if (ch.schema_id != 0 && s.schemas.count(ch.schema_id) == 0) {
        return s.parse_error(at, "channel " + ch.topic + " names schema " +
                                     std::to_string(ch.schema_id) + ", not defined before it");
      }
      s.channels[ch.id] = std::move(ch);
      return false;
    }
    case kMessage: {
      out->channel_id = c.num<uint16_t>();
      out->sequence = c.num<uint32_t>();
      out->log_time_ns = c.num<uint64_t>();
      out->publish_time_ns = c.num<uint64_t>();
      if (!c.ok) return s.parse_error(at, "a malformed Message record");
      if (s.channels.count(out->channel_id) == 0) {
        return s.parse_error(at, "a message on channel " + std::to_string(out->channel_id) +
                                     ", not defined before it");
      }
      out->data.assign(p + c.pos(), p + n);
      return true;
    }
    case kAttachment: {
      McapAttachment a;
      a.log_time_ns = c.num<uint64_t>();
      a.create_time_ns = c.num<uint64_t>();
      a.name = c.str();
      a.media_type = c.str();
      a.data = c.bytes(c.num<uint64_t>());
      const std::size_t crc_at = c.pos();
      const auto crc = c.num<uint32_t>();
      if (!c.ok) return s.parse_error(at, "a malformed Attachment record");
      if (crc != 0 && crc != crc32(std::span<const uint8_t>(p, crc_at))) {
        return s.parse_error(at, "attachment " + a.name + ": its CRC does not match");
      }
      s.attachments.push_back(std::move(a));
      return false;
    }
    case kMetadata: {
      std::string name = c.str();
      auto m = c.map();
      if (!c.ok) return s.parse_error(at, "a malformed Metadata record");
      s.metadata.emplace_back(std::move(name), std::move(m));
      return false;
    }
    case kChunk: {
      (void)c.num<uint64_t>();  // start, end times
      (void)c.num<uint64_t>();
      const auto size = c.num<uint64_t>();
      const auto crc = c.num<uint32_t>();
      const std::string compression = c.str();
      std::vector<uint8_t> records = c.bytes(c.num<uint64_t>());
      if (!c.ok) return s.parse_error(at, "a malformed Chunk record");
      if (!compression.empty()) {
        return s.parse_error(at, "a chunk compressed with " + compression +
                                     " (this reader reads uncompressed chunks only)");
      }
      if (records.size() != size) return s.parse_error(at, "a chunk whose size does not match");
      if (crc != 0 && crc != crc32(records)) {
        return s.parse_error(at, "a chunk whose CRC does not match");
      }
      s.chunk = std::move(records);
      s.chunk_pos = 0;
      s.chunk_offset = at;
      return false;
    }
    default:
      return false;  // indexes, statistics, unknown opcodes: skipped
  }
}

}  // namespace

Result<bool> McapReader::next(McapMessage* out) {
  Impl& s = *impl_;
  std::vector<uint8_t> content;
  for (;;) {
    // Records of the open chunk first.
    while (s.chunk_pos < s.chunk.size()) {
      const std::size_t left = s.chunk.size() - s.chunk_pos;
      if (left < kRecordHeaderBytes) {
        return s.parse_error(s.chunk_offset, "a chunk ends inside a record header");
      }
      const uint8_t op = s.chunk[s.chunk_pos];
      uint64_t len = 0;
      std::memcpy(&len, s.chunk.data() + s.chunk_pos + 1, 8);
      if (len > left - kRecordHeaderBytes) {
        return s.parse_error(s.chunk_offset, "a record runs past the end of its chunk");
      }
      const uint8_t* p = s.chunk.data() + s.chunk_pos + kRecordHeaderBytes;
      s.chunk_pos += kRecordHeaderBytes + static_cast<std::size_t>(len);
      if (op == kChunk) return s.parse_error(s.chunk_offset, "a chunk inside a chunk");
      auto h = handle(s, op, p, static_cast<std::size_t>(len), s.chunk_offset, out);
      if (!h.ok()) return h.error();
      if (*h) return true;
    }
    if (s.done) return false;
    uint8_t op = 0;
    auto got = read_record(s, &op, &content);
    if (!got.ok()) return got.error();
    if (!*got) return s.parse_error(s.offset, "the file ends before its Data End record");
    const uint64_t at = s.offset;
    s.offset += kRecordHeaderBytes + content.size();
    if (op == kDataEnd || op == kFooter) {
      s.done = true;
      return false;
    }
    auto h = handle(s, op, content.data(), content.size(), at, out);
    if (!h.ok()) return h.error();
    if (*h) return true;
  }
}

const std::string& McapReader::profile() const {
  return impl_->profile;
}
const std::map<uint16_t, McapSchema>& McapReader::schemas() const {
  return impl_->schemas;
}
const std::map<uint16_t, McapChannel>& McapReader::channels() const {
  return impl_->channels;
}
const std::vector<McapAttachment>& McapReader::attachments() const {
  return impl_->attachments;
}
const std::vector<std::pair<std::string, std::map<std::string, std::string>>>&
McapReader::metadata() const {
  return impl_->metadata;
}

}  // namespace skinbus::record
