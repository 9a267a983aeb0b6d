// Names of enumerated options, one table per enum: parsing (with a message listing the valid
// names) and naming both read it, so the two cannot drift apart.
#pragma once

#include <cstddef>
#include <stdexcept>
#include <string>

namespace gtbow {

template <typename E>
struct EnumName {
  const char* name;
  E value;
};

// The value called `name`; throws std::invalid_argument "unknown WHAT 'name' (valid: a, b)".
template <typename E, size_t N>
E ParseEnumName(const std::string& name, const char* what, const EnumName<E> (&table)[N]) {
  std::string valid;
  for (const EnumName<E>& e : table) {
    if (name == e.name) return e.value;
    valid += (valid.empty() ? "" : ", ") + std::string(e.name);
  }
  throw std::invalid_argument("unknown " + std::string(what) + " '" + name + "' (valid: " + valid +
                              ")");
}

// The name of `value` ("?" for a value outside the table).
template <typename E, size_t N>
std::string EnumValueName(E value, const EnumName<E> (&table)[N]) {
  for (const EnumName<E>& e : table) {
    if (e.value == value) return e.name;
  }
  return "?";
}

}  // namespace gtbow
