// The pixel type names of PLUS sequence headers: MetaImage's ElementType and NRRD's type.
#include <string>

#include "../io/TextParse.h"
#include "PlusFormat.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace plus {

using namespace text;

PixelType meta_pixel_type(const std::string& name, const std::string& where) {
  const std::string n = upper(trim(name));
  if (n == "MET_UCHAR") return PixelType::UInt8;
  if (n == "MET_CHAR") return PixelType::Int8;
  if (n == "MET_USHORT") return PixelType::UInt16;
  if (n == "MET_SHORT") return PixelType::Int16;
  if (n == "MET_UINT") return PixelType::UInt32;
  if (n == "MET_INT") return PixelType::Int32;
  if (n == "MET_FLOAT") return PixelType::Float32;
  if (n == "MET_DOUBLE") return PixelType::Float64;
  throw InputError(where + ": unsupported ElementType " + quote_value(name) +
                   " (accepted: MET_UCHAR, MET_CHAR, MET_USHORT, MET_SHORT, MET_UINT, MET_INT, "
                   "MET_FLOAT, MET_DOUBLE)");
}

std::string meta_type_name(PixelType t) {
  switch (t) {
    case PixelType::UInt8:
      return "MET_UCHAR";
    case PixelType::Int8:
      return "MET_CHAR";
    case PixelType::UInt16:
      return "MET_USHORT";
    case PixelType::Int16:
      return "MET_SHORT";
    case PixelType::UInt32:
      return "MET_UINT";
    case PixelType::Int32:
      return "MET_INT";
    case PixelType::Float32:
      return "MET_FLOAT";
    case PixelType::Float64:
      break;
  }
  return "MET_DOUBLE";
}

PixelType nrrd_pixel_type(const std::string& name, const std::string& where) {
  // The NRRD format's type names (teem.sourceforge.net/nrrd/format.html#type).
  const std::string n = lower(trim(name));
  if (n == "uchar" || n == "unsigned char" || n == "uint8" || n == "uint8_t")
    return PixelType::UInt8;
  if (n == "signed char" || n == "int8" || n == "int8_t") return PixelType::Int8;
  if (n == "ushort" || n == "unsigned short" || n == "unsigned short int" || n == "uint16" ||
      n == "uint16_t")
    return PixelType::UInt16;
  if (n == "short" || n == "short int" || n == "signed short" || n == "signed short int" ||
      n == "int16" || n == "int16_t")
    return PixelType::Int16;
  if (n == "uint" || n == "unsigned int" || n == "uint32" || n == "uint32_t")
    return PixelType::UInt32;
  if (n == "int" || n == "signed int" || n == "int32" || n == "int32_t") return PixelType::Int32;
  if (n == "float") return PixelType::Float32;
  if (n == "double") return PixelType::Float64;
  throw InputError(where + ": unsupported NRRD type " + quote_value(name) +
                   " (accepted: uint8, int8, uint16, int16, uint32, int32, float, double)");
}

std::string nrrd_type_name(PixelType t) {
  // NRRD's names, except for the two float types.
  if (t == PixelType::Float32) return "float";
  if (t == PixelType::Float64) return "double";
  return to_string(t);
}

}  // namespace plus
}  // namespace sonoslice
