# Generates a C++ file holding every schemas/*.schema.json, so the meshflow binary validates
# workflows without finding files at run time. Run with -DSCHEMA_DIR=... -DOUT=...
# report.schema.json documents report.json for its readers (tests/report): the binary needs it not.
file(GLOB files ${SCHEMA_DIR}/*.schema.json)
list(FILTER files EXCLUDE REGEX "/report\\.schema\\.json$")
list(SORT files)
set(body "// generated from schemas/ by cmake/embed_schemas.cmake: do not edit\n#include <map>\n#include <string>\nnamespace meshflow {\nconst std::map<std::string, std::string>& embedded_schemas() {\n  static const std::map<std::string, std::string> m = {\n")
foreach(f ${files})
  get_filename_component(name ${f} NAME)
  string(REPLACE ".schema.json" "" key ${name})
  file(READ ${f} content)
  string(APPEND body "    {\"${key}\", R\"mfschema(${content})mfschema\"},\n")
endforeach()
string(APPEND body "  };\n  return m;\n}\n}  // namespace meshflow\n")
include(${CMAKE_CURRENT_LIST_DIR}/write_if_changed.cmake)
write_if_changed(${OUT} "${body}")
