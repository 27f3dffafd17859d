// Result types used at every I/O and device boundary.
//
// Runtime failures (bad files, missing devices, unreadable images) are values:
// a function returns Result<T>, and the caller adds context and decides. Bugs
// (broken invariants) are asserts, not Results.
//
// An Error carries a code for decisions (retry on a timeout, resume after a
// disconnect) and the errno where a system call failed; its message is for
// people only. No caller decides anything by searching a message.
#pragma once

#include <cerrno>
#include <expected>
#include <string>
#include <string_view>
#include <utility>

namespace s2r {

enum class ErrorCode {
  failed,        // no more specific kind applies
  invalid,       // an argument or option out of its range
  not_found,     // a file, device or named item that does not exist
  format,        // a file or stream that does not parse or fails validation
  io,            // a read or write that the system refused (errno set)
  timeout,       // no answer within the time allowed
  disconnected,  // the device went away (unplugged, EIO/ENODEV/ENXIO)
  protocol,      // a device answered, but not as its protocol says
  device_fault,  // the device reports a fault of its own (an alarm, a reset)
  unsupported,   // valid, but not something this build or device does
};

// "timeout", "not_found", ...: the code's name as report.json writes it.
constexpr std::string_view error_code_name(ErrorCode c) {
  switch (c) {
    case ErrorCode::failed: return "failed";
    case ErrorCode::invalid: return "invalid";
    case ErrorCode::not_found: return "not_found";
    case ErrorCode::format: return "format";
    case ErrorCode::io: return "io";
    case ErrorCode::timeout: return "timeout";
    case ErrorCode::disconnected: return "disconnected";
    case ErrorCode::protocol: return "protocol";
    case ErrorCode::device_fault: return "device_fault";
    case ErrorCode::unsupported: return "unsupported";
  }
  return "failed";
}

struct Error {
  std::string message;
  ErrorCode code = ErrorCode::failed;
  int sys_errno = 0;  // the errno of the failed system call, 0 if none

  bool is(ErrorCode c) const { return code == c; }
};

template <class T>
using Result = std::expected<T, Error>;
using Status = Result<void>;

inline std::unexpected<Error> fail(std::string message) {
  return std::unexpected(Error{std::move(message)});
}

inline std::unexpected<Error> fail(ErrorCode code, std::string message, int sys_errno = 0) {
  return std::unexpected(Error{std::move(message), code, sys_errno});
}

// The code a failed system call's errno stands for: a device that went away
// (EIO, ENODEV, ENXIO) is `disconnected`, a missing file `not_found`, a wait
// that ran out `timeout`, anything else `io`.
constexpr ErrorCode code_for_errno(int err) {
  switch (err) {
    case EIO:
    case ENXIO:
    case ENODEV:
      return ErrorCode::disconnected;
    case ENOENT:
      return ErrorCode::not_found;
    case ETIMEDOUT:
    case ETIME:
      return ErrorCode::timeout;
    case EOPNOTSUPP:
    case ENOTTY:
      return ErrorCode::unsupported;
    default:
      return ErrorCode::io;
  }
}

// Prefix an error with context: "loading session 'x': <inner>". The code and
// errno are kept.
inline Error with_context(const Error& e, const std::string& context) {
  return Error{context + ": " + e.message, e.code, e.sys_errno};
}

// The same, as a failed result: `return fail_with_context(r.error(), "...")`.
inline std::unexpected<Error> fail_with_context(const Error& e, const std::string& context) {
  return std::unexpected(with_context(e, context));
}

}  // namespace s2r
