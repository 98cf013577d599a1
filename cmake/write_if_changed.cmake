# write_if_changed(FILE CONTENT): writes only when the content differs, so a generated source
# keeps its timestamp (and nothing recompiles) when regeneration produces the same text.
function(write_if_changed file content)
  set(old "")
  if(EXISTS ${file})
    file(READ ${file} old)
  endif()
  if(NOT old STREQUAL content)
    file(WRITE ${file} "${content}")
  endif()
endfunction()
