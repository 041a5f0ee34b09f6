// Errors are values at boundaries: loading, parsing and devices return an
// Expected<T> (a value or an Error with a message that says what, where, and
// how to fix it). C++20 has no std::expected, so this is the small subset the
// project needs. Assertions are reserved for programmer bugs.
#pragma once

#include <cassert>
#include <string>
#include <utility>
#include <variant>

namespace hxmap {

struct Error {
  std::string message;
};

/// A value of T or an Error. Not thread safe (a plain value type).
template <typename T>
class [[nodiscard]] Expected {
 public:
  Expected(T value) : v_(std::move(value)) {}  // NOLINT(google-explicit-constructor)
  Expected(Error error) : v_(std::move(error)) {}  // NOLINT(google-explicit-constructor)

  bool hasValue() const { return v_.index() == 0; }
  explicit operator bool() const { return hasValue(); }

  T& value() & { assert(hasValue()); return std::get<0>(v_); }
  const T& value() const& { assert(hasValue()); return std::get<0>(v_); }
  T&& value() && { assert(hasValue()); return std::get<0>(std::move(v_)); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

  const Error& error() const { assert(!hasValue()); return std::get<1>(v_); }
  const std::string& message() const { return error().message; }

 private:
  std::variant<T, Error> v_;
};

/// Success or an Error, for operations without a result value.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(Error error) : ok_(false), message_(std::move(error.message)) {}  // NOLINT
  static Status ok() { return {}; }

  bool isOk() const { return ok_; }
  explicit operator bool() const { return ok_; }
  const std::string& message() const { return message_; }

 private:
  bool ok_ = true;
  std::string message_;
};

}  // namespace hxmap
