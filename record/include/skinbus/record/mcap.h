// skinbus/record/mcap.h: MCAP files (the container rosbag2 writes and Foxglove, Lichtblick and
// the `mcap` tools read), written and read from the format's specification (version 0):
//
//   magic  Header(profile, library)
//   data:  Schema, Channel, Attachment and Metadata records, and Chunks of Messages, each chunk
//          followed by one Message Index per channel in it
//   DataEnd(crc of the data section)
//   summary: the Schemas and Channels again, Statistics, Chunk, Attachment and Metadata Indexes,
//          then a Summary Offset per group
//   Footer(summary start, summary offset start, summary crc)  magic
//
// Chunks are stored uncompressed (compression ""), with the CRC-32 of their records; a reader
// seeks by the chunk indexes or streams the records. Times are nanoseconds (a ROS 2 bag's:
// since the Unix epoch).
//
// McapWriter writes a file as it goes (a run killed mid-way leaves its complete chunks readable
// by a streaming reader; the summary is written by close()). Allocation: the open chunk (about
// `chunk_bytes`) and O(channels + chunks + attachments) of index. McapReader streams a file
// record by record (memory: one record, at most `max_record_bytes`, and the open chunk), reads
// only uncompressed chunks and names the byte offset of what it cannot read. Errors are values;
// nothing throws. Neither is thread-safe.
#pragma once

#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "skinbus/common/result.h"

namespace skinbus::record {

// The CRC-32 (ISO-HDLC, as zlib's crc32) of `data`, continuing from `crc` (0 to start).
uint32_t crc32(std::span<const uint8_t> data, uint32_t crc = 0);

struct McapWriterOptions {
  std::string profile = "ros2";  // the Header's profile: ros2 for ROS 2 messages in CDR
  std::string library = "skinbus";
  std::size_t chunk_bytes = 1u << 20;  // a chunk is closed once its records reach this size
};

class McapWriter {
 public:
  // Creates (truncates) `path`; kIo naming it when it cannot.
  static Result<std::unique_ptr<McapWriter>> create(const std::string& path,
                                                    McapWriterOptions options = {});
  ~McapWriter();  // closes the file; call close() to finish it (the destructor only flushes)
  McapWriter(const McapWriter&) = delete;
  McapWriter& operator=(const McapWriter&) = delete;

  // A schema (`encoding` e.g. "ros2msg", `data` its definition text) and a channel (topic,
  // message encoding e.g. "cdr", metadata); each returns its ID (from 1). Written at once.
  uint16_t add_schema(const std::string& name, const std::string& encoding,
                      std::span<const uint8_t> data);
  uint16_t add_channel(uint16_t schema_id, const std::string& topic,
                       const std::string& message_encoding,
                       const std::map<std::string, std::string>& metadata = {});

  // One message of `channel_id` (an ID add_channel returned; others kInvalidArgument), logged at
  // `log_time_ns`, published at `publish_time_ns`. Its sequence number counts per channel.
  Status write_message(uint16_t channel_id, uint64_t log_time_ns, uint64_t publish_time_ns,
                       std::span<const uint8_t> data);
  // A file attached (written outside chunks, with its CRC) and a named string map.
  Status write_attachment(const std::string& name, const std::string& media_type,
                          std::span<const uint8_t> data, uint64_t log_time_ns,
                          uint64_t create_time_ns);
  Status write_metadata(const std::string& name, const std::map<std::string, std::string>& map);

  // Ends the data section, writes the summary and the footer and closes the file. kIo on a
  // failed write (the first failure of any call is kept and returned here too).
  Status close();

  uint64_t bytes_written() const;
  uint64_t message_count() const;

  struct Impl;

 private:
  McapWriter(std::FILE* f, std::string path, McapWriterOptions options);
  std::unique_ptr<Impl> impl_;
};

struct McapSchema {
  uint16_t id = 0;
  std::string name, encoding;
  std::vector<uint8_t> data;
};
struct McapChannel {
  uint16_t id = 0, schema_id = 0;
  std::string topic, message_encoding;
  std::map<std::string, std::string> metadata;
};
struct McapMessage {
  uint16_t channel_id = 0;
  uint32_t sequence = 0;
  uint64_t log_time_ns = 0, publish_time_ns = 0;
  std::vector<uint8_t> data;
};
struct McapAttachment {
  std::string name, media_type;
  uint64_t log_time_ns = 0, create_time_ns = 0;
  std::vector<uint8_t> data;
};

struct McapReaderOptions {
  uint64_t max_record_bytes = 256u << 20;  // a record (or chunk) longer than this is refused
};

class McapReader {
 public:
  // Opens `path` and reads its magic and header; kNotFound / kIo / kParse naming it.
  static Result<std::unique_ptr<McapReader>> open(const std::string& path,
                                                  McapReaderOptions options = {});
  // The same over an open stream (borrowed; a fuzz target's memory stream); `name` for errors.
  static Result<std::unique_ptr<McapReader>> open(std::FILE* f, const std::string& name,
                                                  McapReaderOptions options = {});
  ~McapReader();
  McapReader(const McapReader&) = delete;
  McapReader& operator=(const McapReader&) = delete;

  // The next message in file order into `out`: true, or false at the end of the data section.
  // Schemas, channels, attachments and metadata met on the way are kept (below). kParse naming
  // the file and byte offset for a malformed record, a message on a channel not yet defined,
  // a chunk whose CRC does not match or that is compressed, a file that ends early.
  Result<bool> next(McapMessage* out);

  const std::string& profile() const;
  const std::map<uint16_t, McapSchema>& schemas() const;
  const std::map<uint16_t, McapChannel>& channels() const;
  const std::vector<McapAttachment>& attachments() const;
  const std::vector<std::pair<std::string, std::map<std::string, std::string>>>& metadata() const;

  struct Impl;

 private:
  McapReader();
  std::unique_ptr<Impl> impl_;
};

}  // namespace skinbus::record
