include(CMakePackageConfigHelpers)
# Installed under the names the build tree uses: slurry::slurry, slurry::run, slurry::io,
# slurry::engine, slurry::transfer, slurry::constitutive (and slurry::parallel, the threading
# backend they link). The OpenVDB outputs (slurry::vdb) are the CLI's module and not installed
# as a library, nor are their headers.
set_target_properties(slurry_engine PROPERTIES EXPORT_NAME engine)
set_target_properties(slurry_io PROPERTIES EXPORT_NAME io)
set_target_properties(slurry_run PROPERTIES EXPORT_NAME run)
set_target_properties(slurry_transfer PROPERTIES EXPORT_NAME transfer)
set_target_properties(slurry_constitutive PROPERTIES EXPORT_NAME constitutive)
set_target_properties(slurry_parallel PROPERTIES EXPORT_NAME parallel)
install(TARGETS slurry slurry_constitutive slurry_transfer slurry_engine slurry_io slurry_run slurry_parallel
        EXPORT SlurryTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
        LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
        RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR}
        INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
foreach(part constitutive transfer engine)
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/${part}/include/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
endforeach()
install(DIRECTORY ${PROJECT_SOURCE_DIR}/io/include/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}
        PATTERN surface.h EXCLUDE PATTERN pipeline.h EXCLUDE)
install(EXPORT SlurryTargets NAMESPACE slurry:: DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/Slurry)
configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/SlurryConfig.cmake.in
  ${PROJECT_BINARY_DIR}/SlurryConfig.cmake INSTALL_DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/Slurry)
write_basic_package_version_file(${PROJECT_BINARY_DIR}/SlurryConfigVersion.cmake COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/SlurryConfig.cmake ${PROJECT_BINARY_DIR}/SlurryConfigVersion.cmake
        DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/Slurry)
