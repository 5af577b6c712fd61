"""The system around the driver: doctor, udev rules, the compiled-code cache and the first run's
compile, camera serials and their config folders, optional extras, the guard process."""
