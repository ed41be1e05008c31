/* steval-link firmware patch: compile-time options.
 *
 * Every option can be set on the compiler command line (-DNAME=value, the Makefile does it from its own
 * variables) or by editing the defaults below. The status frame reports the options in force, so the host
 * replays a build with the matching settings.
 */
#ifndef STV_CONFIG_H
#define STV_CONFIG_H

/* USART1 baud rate (8N1). 115200 carries the attitude + status stream at 85.0 % load; 921600 leaves ample room. */
#ifndef STV_BAUD
#define STV_BAUD 115200u
#endif

/* 0: binary frames (PROTOCOL.md); 1: text mode ($ATT / $STA lines with NMEA checksums, plain log lines). */
#ifndef STV_TEXT_MODE
#define STV_TEXT_MODE 0
#endif

/* Text mode: one $ATT line every STV_TEXT_DECIMATION AHRS steps (16: about 10 lines/s). */
#ifndef STV_TEXT_DECIMATION
#define STV_TEXT_DECIMATION 16u
#endif

/* A status frame (or $STA line) after every STV_STATUS_EVERY_STEPS AHRS steps (162 steps = 1.003 s). */
#ifndef STV_STATUS_EVERY_STEPS
#define STV_STATUS_EVERY_STEPS 162u
#endif

/* Bytes of the TX ring buffer (a power of two, at least 512). 2048 bytes = 178 ms of output at 115200 baud. */
#ifndef STV_TXQ_SIZE
#define STV_TXQ_SIZE 2048u
#endif

/* Lab exercise 4: the integral gain of ahrs.c (ST's value 0.1f; the exercise sets 1.0f).
 * The patch makes Inc/ahrs.h take AHRS_KI from here. */
#ifndef AHRS_KI
#define AHRS_KI 0.1f
#endif

/* Lab exercise 5: 1 = no accelerometer correction (g* = g; correction steps 2-5 of ahrs_fusion_ag compiled out,
 * so exInt/eyInt/ezInt stay 0). Reported in status flags bit 0. */
#ifndef AHRS_NO_CORRECTION
#define AHRS_NO_CORRECTION 0
#endif

/* Version of this patch, sent in the status frame (major, minor, patch). */
#define STV_FW_VERSION_MAJOR 2u
#define STV_FW_VERSION_MINOR 0u

#if (STV_TXQ_SIZE & (STV_TXQ_SIZE - 1u)) != 0 || STV_TXQ_SIZE < 512u
#error "STV_TXQ_SIZE must be a power of two >= 512"
#endif
#if STV_TEXT_DECIMATION < 1
#error "STV_TEXT_DECIMATION must be >= 1"
#endif
#if STV_STATUS_EVERY_STEPS < 1
#error "STV_STATUS_EVERY_STEPS must be >= 1"
#endif

#endif /* STV_CONFIG_H */
