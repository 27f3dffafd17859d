// Result types used at every I/O and device boundary.
//
// Runtime failures (bad files, missing devices, unreadable images) are values:
// a function returns Result<T>, and the caller adds context and decides. Bugs
// (broken invariants) are asserts, not Results.
#pragma once

#include <expected>
#include <string>
#include <utility>

namespace s2r {

struct Error {
  std::string message;
};

template <class T>
using Result = std::expected<T, Error>;
using Status = Result<void>;

inline std::unexpected<Error> fail(std::string message) {
  return std::unexpected(Error{std::move(message)});
}

// Prefix an error with context: "loading session 'x': <inner>".
inline Error with_context(const Error& e, const std::string& context) {
  return Error{context + ": " + e.message};
}

}  // namespace s2r
