"""Public data sets as bags: the KTH ute (Car Park, Victoria Park) and UTIAS MRCLAM, with online-em-slam-convert."""
