#include "skinbus/record/cdr.h"

#include <bit>

namespace skinbus::record {

static_assert(std::endian::native == std::endian::little, "CDR_LE is written as memory holds it");

namespace {
constexpr std::size_t kHeaderBytes = 4;
constexpr uint8_t kCdrLe = 0x01;
}  // namespace

CdrWriter::CdrWriter(std::vector<uint8_t>* out) : out_(out) {
  out_->assign({0x00, kCdrLe, 0x00, 0x00});
}

void CdrWriter::put(const void* v, std::size_t size, std::size_t align) {
  const std::size_t at = out_->size() - kHeaderBytes;
  const std::size_t pad = (align - at % align) % align;
  out_->insert(out_->end(), pad, 0);
  const auto* p = static_cast<const uint8_t*>(v);
  out_->insert(out_->end(), p, p + size);
}

void CdrWriter::string(std::string_view s) {
  u32(static_cast<uint32_t>(s.size() + 1));
  out_->insert(out_->end(), s.begin(), s.end());
  out_->push_back(0);
}

void CdrWriter::bytes(std::span<const uint8_t> data) {
  count(data.size());
  out_->insert(out_->end(), data.begin(), data.end());
}

CdrReader::CdrReader(std::span<const uint8_t> data, std::string what)
    : data_(data), what_(std::move(what)) {
  if (data_.size() < kHeaderBytes) {
    fail("encapsulation header", "the message is shorter than its 4-byte header");
  } else if (data_[0] != 0x00 || data_[1] != kCdrLe) {
    fail("encapsulation header", "not little-endian plain CDR (00 01)");
  } else {
    pos_ = kHeaderBytes;
  }
}

void CdrReader::fail(const char* field, std::string_view why) {
  if (!error_.empty()) return;
  error_ = std::string(field) + " at byte " + std::to_string(pos_) + ": " + std::string(why);
  pos_ = data_.size();
}

bool CdrReader::take(std::size_t size, std::size_t align, const char* field) {
  if (!error_.empty()) return false;
  const std::size_t at = pos_ - kHeaderBytes;
  const std::size_t pad = (align - at % align) % align;
  if (remaining() < pad || remaining() - pad < size) {
    fail(field, "the message ends");
    return false;
  }
  pos_ += pad + size;
  return true;
}

std::string CdrReader::string(const char* field) {
  const uint32_t n = u32(field);
  if (!ok()) return {};
  if (n == 0 || n > remaining()) {
    fail(field, n == 0 ? "a string without its terminating NUL" : "the string runs past the end");
    return {};
  }
  const char* p = reinterpret_cast<const char*>(data_.data() + pos_);
  if (p[n - 1] != '\0') {
    fail(field, "a string without its terminating NUL");
    return {};
  }
  pos_ += n;
  return std::string(p, n - 1);
}

uint32_t CdrReader::count(const char* field, std::size_t min_element_bytes) {
  const uint32_t n = u32(field);
  if (!ok()) return 0;
  if (min_element_bytes > 0 && n > remaining() / min_element_bytes) {
    fail(field, "a count of " + std::to_string(n) + " elements does not fit in the message");
    return 0;
  }
  return n;
}

std::vector<uint8_t> CdrReader::bytes(const char* field) {
  const uint32_t n = count(field, 1);
  if (!ok()) return {};
  std::vector<uint8_t> out(data_.begin() + static_cast<std::ptrdiff_t>(pos_),
                           data_.begin() + static_cast<std::ptrdiff_t>(pos_ + n));
  pos_ += n;
  return out;
}

Status CdrReader::status() const {
  if (error_.empty()) return Status::Ok();
  return make_error(ErrorCode::kParse, what_ + ": " + error_);
}

}  // namespace skinbus::record
